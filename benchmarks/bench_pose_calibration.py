"""Benchmark: pose-camera calibration (``--calibrate-poses``) on a SIMULATED hand-held sequence
whose poses belong to another body, against the same sequence with the camera's own poses.

The sequence: the bundled room scene rendered (``vio_depth.simulate``) along the room
sample's walk with a fast hand-held oscillation on top (yaw 20 deg at 0.8 Hz, pitch 12 deg
at 1.1 Hz, roll 8 deg at 0.6 Hz: up to ~100 deg/s), 30 Hz, SIMULATED disparity from the
rendered depth. Two folders share the images and differ only in ``poses.txt``:

* ``camera``: the camera's exact poses (the baseline: "perfect poses");
* ``body``: the poses of a body the camera is mounted on with a known offset,
  ``T_w_b(t) = T_w_c(t - dt) T_b_c^-1``: ``dt`` = 15 ms, ``T_b_c`` = 3 cm and 2 deg.

Both are marked as not exact (``metadata.simulated`` false: poses from a tracker), so
``--calibrate-poses auto`` estimates. Runs: ``vio-depth run FOLDER --pairing indoor
--max-depth 10 --calibrate-poses auto|off`` (two-view points; ``--paths`` adds landmarks),
each with the poses' stated uncertainty (``--trust``): ``stated``, the ``mocap`` preset the
run takes for such poses (0.1 deg, 2 mm + 1 %, 5 ms: its refusals act), and ``exact``, the
poses taken as exact (no covariance: what the offset alone does to depth).
Columns: the estimate (time offset, rotation, translation, whether applied), ``AbsRel`` /
``delta1`` (frame-averaged over frames with depth), ``oracle``, ``depth`` (frames given
depth), ``bad ok``: frames with status ``ok`` whose AbsRel exceeds 2 x their oracle + 0.02.
The check: ``body`` with ``auto`` within 1.1 x the AbsRel of ``camera`` with ``off``, and
the offsets recovered (2 ms, 5 mm, 0.2 deg).

Real data: when ``DATA/7scenes_redkitchen`` exists (``--data``, default ``../shared/data``),
the estimate on its frames 0-299 (KinectFusion poses of the depth camera, mapped to the
colour camera by the loader's generic Kinect extrinsic) is printed too (estimate only, no
run).

Run: ``python benchmarks/bench_pose_calibration.py [--frames 90] [--work DIR]
[--paths two-view,landmarks] [--data DIR]``; ``--work`` keeps the rendered folders (and
reuses them).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run as a script from anywhere: this checkout's packages first
    sys.path.insert(0, str(REPO))

from scipy.spatial.transform import Rotation  # noqa: E402

from matchers import create_matcher  # noqa: E402
from vio_depth import Pipeline, PipelineSettings, open_sequence  # noqa: E402
from vio_depth.disparity import DisparitySpec, disparity_preset  # noqa: E402
from vio_depth.io.native_writer import NativeSequenceWriter  # noqa: E402
from vio_depth.poses import (  # noqa: E402
    POSE_UNCERTAINTY_PRESETS,
    GroundTruthPoseSettings,
    estimate_pose_calibration,
)
from vio_depth.run import RunSettings, read_frames_jsonl, run_sequence  # noqa: E402
from vio_depth.simulate.generate import camera_poses, sample_spec  # noqa: E402
from vio_depth.simulate.render import render_view  # noqa: E402
from vio_depth.simulate.scene_library import build_scene  # noqa: E402

RATE_HZ = 30.0
FIRST_S = 0.5
TRUE_DT = 0.015
TRUE_T_B_C = np.eye(4)
TRUE_T_B_C[:3, :3] = Rotation.from_rotvec(math.radians(2.0) * np.array([1.0, 2.0, 2.0]) / 3.0).as_matrix()
TRUE_T_B_C[:3, 3] = [0.03, 0.0, 0.0]
PATHS = {"two-view": "sfm", "landmarks": "landmarks"}


def camera_trajectory(t) -> np.ndarray:
    """(K, 4, 4) camera-to-world: the room sample's walk with a fast hand-held oscillation."""
    spec = sample_spec("room")
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    base = camera_poses(spec, spec.make_trajectory(spec.seed), t)
    euler = np.stack([math.radians(a) * np.sin(2 * np.pi * f * t + ph)
                      for a, f, ph in ((20.0, 0.8, 0.0), (12.0, 1.1, 1.0), (8.0, 0.6, 2.0))], axis=1)
    osc = np.tile(np.eye(4), (len(t), 1, 1))
    osc[:, :3, :3] = Rotation.from_euler("yxz", euler).as_matrix()  # camera axes: yaw about y (down)
    return base @ osc


def write_sequences(work: Path, n: int) -> dict[str, Path]:
    """Render ``n`` frames once and write the ``camera`` and ``body`` folders (reused when present)."""
    spec = sample_spec("room")
    folders = {"camera": work / "camera", "body": work / "body"}
    if all((f / "sequence.json").is_file() and len(open_sequence(f)) == n for f in folders.values()):
        return folders
    ts = FIRST_S + np.arange(n) / RATE_HZ
    poses = {"camera": camera_trajectory(ts), "body": camera_trajectory(ts - TRUE_DT) @ np.linalg.inv(TRUE_T_B_C)}
    scene = build_scene(spec.scene, spec.scene_seed)
    writers = {}
    for name, folder in folders.items():
        note = ("the camera's exact poses" if name == "camera" else
                f"the poses of a body: T_w_b(t) = T_w_c(t - {TRUE_DT}) T_b_c^-1, T_b_c 3 cm / 2 deg")
        meta = {"simulated": False, "rendered": True,
                "description": f"SIMULATED hand-held room (rendered, not real), fast rotation; poses: {note}"}
        writers[name] = NativeSequenceWriter(folder, f"room_fast_{name}", spec.camera, image_ext=".png",
                                             metadata=meta, overwrite=True)
        writers[name].set_disparity(DisparitySpec.simulated(spec.disparity_seed, disparity_preset("default")))
    start = time.perf_counter()
    for i, t in enumerate(ts):
        view = render_view(scene, spec.camera, poses["camera"][i], settings=spec.render, noise_seed=[spec.seed, 5, i])
        for name, w in writers.items():
            w.add_frame(float(t), view.image, poses[name][i], depth=view.depth)
        if (i + 1) % 15 == 0:
            print(f"  rendered {i + 1}/{n} frames ({time.perf_counter() - start:.0f} s)", flush=True)
    for w in writers.values():
        w.close()
    return folders


def run(folder: Path, path: str, calibrate: str, trust: str, out: Path) -> tuple[dict, list[dict]]:
    sequence = open_sequence(folder)
    settings = PipelineSettings.from_presets(points=PATHS[path], pairing="indoor")
    if trust == "exact":
        settings = replace(settings, poses=GroundTruthPoseSettings(uncertainty=POSE_UNCERTAINTY_PRESETS["exact"]))
    run_sequence(sequence, Pipeline(settings, sequence=sequence), out,
                 RunSettings(max_eval_depth=10.0, calibrate_poses=calibrate), progress=False)
    return json.loads((out / "metrics.json").read_text()), read_frames_jsonl(out / "frames.jsonl")[1]


def row(label: str, path: str, metrics: dict, frames: list[dict]) -> tuple[str, float]:
    m = metrics["metrics"].get(PATHS[path], {})
    oracle = metrics["metrics"].get("oracle", {})
    bad = [f["frame"] for f in frames if f["status"] == "ok" and f.get("abs_rel") is not None
           and f.get("oracle_abs_rel") is not None and f["abs_rel"] > 2 * f["oracle_abs_rel"] + 0.02]
    c = metrics.get("pose_calibration") or {}
    if c.get("estimated"):
        est = (f"{c['time_offset_s'] * 1e3:6.1f} {c['rotation_deg']:5.2f} {c['translation_m'] * 1e3:5.1f} "
               f"{'yes' if c['applied'] else 'no':>4s}")
    else:
        est = f"{'-':>6s} {'-':>5s} {'-':>5s} {'no':>4s}"
    abs_rel = m.get("abs_rel", float("nan"))
    line = (f"{label:22s} {est} {abs_rel:7.4f} {m.get('delta1', float('nan')):7.4f} "
            f"{oracle.get('abs_rel', float('nan')):7.4f} "
            f"{metrics['frames_with_depth']:3d}/{metrics['frames_processed']:<3d} "
            f"{len(bad):6d}")
    statuses = ", ".join(f"{k} {v}" for k, v in sorted(metrics["status_counts"].items()))
    line += f"\n  statuses: {statuses}"
    if c:
        line += f"\n  calibration: {c['reason']}"
    if bad:
        line += f"\n  ok frames above 2 x oracle + 0.02: {bad[:30]}" + (" ..." if len(bad) > 30 else "")
    return line, abs_rel


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--work", type=Path, default=None, help="keep (and reuse) the rendered folders here")
    parser.add_argument("--paths", default="two-view")
    parser.add_argument("--trust", default="stated,exact", help="the poses' stated uncertainty: stated, exact")
    parser.add_argument("--data", type=Path, default=REPO / ".." / "shared" / "data")
    args = parser.parse_args(argv)
    print(f"bench_pose_calibration, {datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPU cores, "
          f"python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}")
    print(f"SIMULATED room, {args.frames} frames at {RATE_HZ:g} Hz, fast rotation; SIMULATED disparity; truth: "
          f"time offset {TRUE_DT * 1e3:g} ms, T_b_c 2 deg / 30 mm")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp) / "sequences"
        folders = write_sequences(work, args.frames)
        head = (f"{'run':22s} {'dt ms':>6s} {'rot':>5s} {'t mm':>5s} {'appl':>4s} {'AbsRel':>7s} {'delta1':>7s} "
                f"{'oracle':>7s} {'depth':>7s} {'bad ok':>6s}")
        ok = True
        for path, trust in [(p, t) for p in args.paths.split(",") for t in args.trust.split(",")]:
            print(f"\n{path} points (--pairing indoor --max-depth 10), pose uncertainty {trust}\n{head}")
            results = {}
            for poses, calibrate in (("camera", "off"), ("camera", "auto"), ("body", "off"), ("body", "auto")):
                t0 = time.perf_counter()
                metrics, frames = run(folders[poses], path, calibrate, trust,
                                      Path(tmp) / f"{path}_{trust}_{poses}_{calibrate}")
                line, results[poses, calibrate] = row(f"{poses} poses, {calibrate}", path, metrics, frames)
                print(line + f"\n  {time.perf_counter() - t0:.0f} s", flush=True)
                if (poses, calibrate) == ("body", "auto"):
                    c = metrics["pose_calibration"]
                    T = np.array(c["T_b_c"])
                    rot_err = math.degrees(float(np.linalg.norm(
                        Rotation.from_matrix(T[:3, :3].T @ TRUE_T_B_C[:3, :3]).as_rotvec())))
                    errors = (abs(c["time_offset_s"] - TRUE_DT) * 1e3,
                              float(np.linalg.norm(T[:3, 3] - TRUE_T_B_C[:3, 3])) * 1e3, rot_err)
                    print(f"  recovered: time offset error {errors[0]:.2f} ms, translation error {errors[1]:.1f} mm, "
                          f"rotation error {errors[2]:.3f} deg")
                    ok &= bool(c["applied"]) and errors[0] <= 2.0 and errors[1] <= 5.0 and errors[2] <= 0.2
            ratio = results["body", "auto"] / results["camera", "off"]
            print(f"AbsRel body/auto vs camera/off: x{ratio:.3f} (target <= 1.1)")
            if math.isfinite(ratio):
                ok &= ratio <= 1.1
            else:
                print("  (no frame with depth to compare)")
    seven = args.data / "7scenes_redkitchen"
    if seven.exists():
        sequence = open_sequence(seven)
        frames = [sequence.frame(i) for i in range(min(300, len(sequence)))]
        c = estimate_pose_calibration(frames, create_matcher("sift"))
        print(f"\n7-Scenes redkitchen frames 0-{len(frames) - 1} (real; poses '{sequence.pose_kind}'), SIFT, "
              f"{c.seconds:.0f} s:\n  {c.summary()}")
    else:
        print(f"\n{seven} missing: no real-data estimate")
    print("\nPASS" if ok else "\nFAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
