"""IMU-only propagation error and covariance consistency (NEES) of ``--poses imu``.

For each sequence and window length (0.25 / 0.5 / 1 s) the IMU pose source predicts the
relative camera pose from a keyframe to the frame one window later, with the keyframe's
orientation from the ground truth and its velocity and biases estimated from the ground
truth poses up to the keyframe (see :mod:`vio_depth.evaluation.imu_propagation`). Reported
per covariance setting, all in the same run:

* ``uncalibrated`` -- the named baseline: datasheet white noise only (the covariance
  before the calibration, ``ImuPoseSettings.uncalibrated()``);
* ``imu`` -- the default (pose preset ``imu``): plus the bias estimate's error and the
  two-pose velocity's pose noise;
* ``imu_real_mav`` -- pose preset: ``imu`` with the accelerometer noise x10 (calibrated on
  the first half of the EuRoC stream: ``euroc_A``; ``euroc_B`` is the held-out second half).

Columns: median / p90 relative translation error (intervals moving >= 5 cm), median
rotation error, and per 3-dof block the median NEES and the fraction below the 95 %
chi-square bound (consistent: median 2.37, 95 %).

Sequences: the real EuRoC V1_01 IMU stream with its ground truth
(``../shared/data/euroc_v101_static``, frames at 20 Hz from the 200 Hz ground truth;
skipped when absent) and the bundled SIMULATED samples ``street`` (10 Hz frames: the
0.25 s window is 0.3 s there) and ``room`` (20 Hz).

    python benchmarks/bench_imu.py                  # everything (a few minutes on 2 cores)
    python benchmarks/bench_imu.py --sequences room --stride 4
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import numpy as np

from vio_depth.evaluation import evaluate_propagation, ground_truth_frames
from vio_depth.io import open_sequence
from vio_depth.pipeline import POSE_PRESETS
from vio_depth.poses import ImuPoseSettings

ROOT = Path(__file__).resolve().parents[1]
EUROC = ROOT / ".." / "shared" / "data" / "euroc_v101_static"
#: the covariance settings compared, baseline first
SETTINGS = {"uncalibrated": ImuPoseSettings.uncalibrated(), "imu": POSE_PRESETS["imu"],
            "imu_real_mav": POSE_PRESETS["imu_real_mav"]}
WINDOWS = (0.25, 0.5, 1.0)


def load(name: str):
    """``(imu, frames, stride)`` of a benchmark sequence, or None when its data are absent."""
    if name.startswith("euroc"):
        if not EUROC.is_dir():
            return None
        seq = open_sequence(EUROC)
        gt = seq.ground_truth
        frames = ground_truth_frames(gt.t, gt.T_w_i, seq.imu.T_c_i, seq.camera, 20.0, margin_s=0.2)
        half = len(frames) // 2
        frames = {"euroc": frames, "euroc_A": frames[:half], "euroc_B": frames[half:]}[name]
        return seq.imu, frames, 10
    root = ROOT / "sample_sequences" / name
    if not (root / "sequence.json").is_file():
        return None
    seq = open_sequence(root)
    return seq.imu, list(seq), 2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", nargs="+", default=["euroc", "euroc_A", "euroc_B", "street", "room"])
    parser.add_argument("--stride", type=int, default=None, help="keyframe stride (default: 10 EuRoC, 2 samples)")
    args = parser.parse_args(argv)
    print(f"# machine: {platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, "
          f"numpy {np.__version__}")
    header = ("| sequence | setting | window s | intervals | rel. transl. median | p90 | rotation median deg "
              "| NEES transl. median | within 95 % | NEES rot. median | within 95 % |")
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    missing = []
    for name in args.sequences:
        data = load(name)
        if data is None:
            missing.append(name)
            continue
        imu, frames, stride = data
        for setting, settings in SETTINGS.items():
            res = evaluate_propagation(imu, frames, WINDOWS, settings=settings,
                                       stride=args.stride or stride)
            for W, r in res.items():
                s = r.summary()
                print(f"| {name} | {setting} | {s['dt_s']:.2f} | {s['n']} | {100 * s['rel_translation_median']:.2f} % "
                      f"| {100 * s['rel_translation_p90']:.2f} % | {s['rotation_median_deg']:.3f} "
                      f"| {s['nees_translation_median']:.2f} | {100 * s['nees_translation_within_95']:.0f} % "
                      f"| {s['nees_rotation_median']:.2f} | {100 * s['nees_rotation_within_95']:.0f} % |", flush=True)
    if missing:
        print(f"# skipped (data absent): {', '.join(missing)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
