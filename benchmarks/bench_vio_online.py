"""The odometry as a robot sees it: ``--poses vio_offline`` (``vio`` until 2026-12-07: the window
inline; ``vio`` is now the camera-rate configuration, measured by bench_realtime.py) streamed
through ``FrameStream``, each frame's pose taken when the frame is processed (no offline backward
pass), against the sequence's ground truth; for checking that a cheaper setting of the landmark
window keeps its accuracy (issue 24).

Sequences (all SIMULATED: rendered images, IMU and disparity):

* ``asl_room``: the generated ASL sample (room, 80 frames, 20 Hz; rendered once into the cache
  of ``bench_realtime.py``), disparity from its files;
* ``room`` / ``street``: the bundled samples (``--pairing indoor`` and an evaluation cap of 10 m
  for room; the default pairing and 80 m for street), disparity simulated from their depth.

Columns: frames posed when processed, **online ATE** (positions, SE(3)-aligned by Umeyama, no
scale correction; metres), frames with depth and their dense AbsRel against the ground-truth
depth (not for ``asl_room``, which has none), mean ms of the ``poses`` stage and of the whole
push; ``wrong``: frames with depth whose AbsRel exceeds 2 x their own oracle (least-squares
fit of the same disparity to the truth, :func:`~vio_depth.evaluation.metrics.oracle_fit`) +
0.02 (listed: frame index, its AbsRel and the predicted error of its fit); ``update CPU ms``: mean CPU (thread) milliseconds of the window's keyframe updates
(``LandmarkWindow.add_keyframe``, inline) -- e.g. ``--set solver='isam2'`` against the batch
window. The named baseline is the **default settings**, run first in the same invocation; each
``--set`` runs once more with ``FIELD=VALUE`` changed (a field of ``VioSettings.window``,
i.e. ``LandmarkSettings``, or else of ``VioSettings``).

    python benchmarks/bench_vio_online.py --matcher klt --set lm_min_error_decrease=1e-5
    python benchmarks/bench_vio_online.py --sequences room,street --set window_keyframes=12 --set ba_max_landmarks=400
    python benchmarks/bench_vio_online.py --matcher klt --set "backend=('process', 6)"   # the window in a worker
    python benchmarks/bench_vio_online.py --set "backend=('process', 3); solver='isam2'"  # two changes, one run
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]  # measure this checkout's code

import numpy as np  # noqa: E402

import realtime_data as data  # noqa: E402
from bench_realtime import DEFAULT_CACHE, parse_vio_changes, with_changes  # noqa: E402
from vio_depth import FrameStream, PipelineSettings, open_sequence  # noqa: E402
from vio_depth.disparity import FileDisparity, SimulatedDisparitySource  # noqa: E402
from vio_depth.evaluation import umeyama_alignment  # noqa: E402
from vio_depth.evaluation.metrics import oracle_fit  # noqa: E402
from vio_depth.landmarks import LandmarkWindow  # noqa: E402

SEQUENCES = {"asl_room": ("indoor", None), "room": ("indoor", 10.0), "street": (None, 80.0)}


def aligned_ate(est: np.ndarray, ref: np.ndarray) -> float:
    """RMSE (metres) of positions ``est: (N, 3)`` after the rigid motion that best maps them onto
    ``ref: (N, 3)`` (:func:`vio_depth.evaluation.umeyama_alignment`, no scale)."""
    R, t, _ = umeyama_alignment(est, ref)
    return float(np.sqrt(np.mean(np.sum((est @ R.T + t - ref) ** 2, axis=1))))


def run(name: str, matcher: str, changes: dict, cache: Path) -> dict:
    pairing, max_depth = SEQUENCES[name]
    if name == "asl_room":
        data.asl_room(cache)  # renders it on first use
        folder = cache / "asl_room"
        disparity = FileDisparity(folder / "disparity")
    else:
        folder = ROOT / "sample_sequences" / name
        disparity = SimulatedDisparitySource(0)
    seq = open_sequence(folder)
    settings = PipelineSettings.from_presets(poses="vio_offline", pairing=pairing, matcher=matcher)
    if matcher == "klt":  # its corners sit on depth edges (bench_realtime's klt rows do the same)
        settings = replace(settings, rescaler=replace(settings.rescaler, max_disparity_spread=0.1))
    stream = FrameStream(seq.camera, with_changes(settings, changes), imu_calibration=seq.imu,
                         pose_kind=seq.pose_kind)
    imu, done = seq.imu, -np.inf
    est, ref, abs_rel, poses_s, total_s, wrong = [], [], [], [], [], []
    # CPU seconds of the window's keyframe updates (inline: in the calling thread)
    update_cpu, add_keyframe = [], LandmarkWindow.add_keyframe

    def timed(self, *args, **kwargs):
        start = time.thread_time()
        try:
            return add_keyframe(self, *args, **kwargs)
        finally:
            update_cpu.append(time.thread_time() - start)

    LandmarkWindow.add_keyframe = timed
    for i in range(len(seq)):
        frame = seq[i]
        new = (imu.t > done) & (imu.t <= frame.timestamp)
        done = frame.timestamp
        d = disparity(frame)
        start = time.perf_counter()
        r = stream.push(frame.image(), d, timestamp=frame.timestamp,
                        imu=(imu.t[new], imu.gyro[new], imu.accel[new]))
        total_s.append(time.perf_counter() - start)
        poses_s.append(r.timings.get("poses", 0.0))
        if r.frame_pose is not None and r.frame_pose.ok:
            est.append(r.frame_pose.T_w_c[:3, 3])
            ref.append(frame.T_w_c[:3, 3])
        gt = None if max_depth is None else frame.gt_depth()
        if r.depth is not None and gt is not None:
            m = np.isfinite(r.depth) & (gt > 0) & (gt < max_depth)
            abs_rel.append(float(np.mean(np.abs(r.depth[m] - gt[m]) / gt[m])))
            fit = oracle_fit(d, gt, max_depth=max_depth)
            oracle = 1.0 / np.maximum(fit.alpha * d[m] + fit.beta, 1e-9)
            if abs_rel[-1] > 2 * float(np.nanmean(np.abs(oracle - gt[m]) / gt[m])) + 0.02:
                predicted = r.rescale.predicted_error if r.rescale is not None else None
                wrong.append(f"{i} ({100 * abs_rel[-1]:.1f} %, predicted "
                             f"{'-' if predicted is None else f'{100 * predicted:.1f} %'})")
    LandmarkWindow.add_keyframe = add_keyframe
    return {"wrong": wrong, "updates": len(update_cpu),
            "update_cpu_ms": 1000 * float(np.mean(update_cpu)) if update_cpu else float("nan"),"posed": f"{len(est)}/{len(seq)}",
            "ate_mm": 1000 * aligned_ate(np.array(est), np.array(ref)) if len(est) >= 3 else float("nan"),
            "depth": len(abs_rel), "abs_rel": float(np.mean(abs_rel)) if abs_rel else float("nan"),
            "poses_ms": 1000 * float(np.mean(poses_s)), "total_ms": 1000 * float(np.mean(total_s))}


def parse_change(text: str) -> tuple[str, dict]:
    """``--set``'s ``FIELD=VALUE`` (or several, ``;``-separated: one run with all of them) as
    ``(text, {field: value})``."""
    try:
        return text, parse_vio_changes(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--set: {exc}") from None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", default=",".join(SEQUENCES), help=f"comma-separated, of {', '.join(SEQUENCES)}")
    parser.add_argument("--matcher", default="klt", help="the pipeline's --matcher preset (default klt)")
    parser.add_argument("--set", dest="changes", action="append", type=parse_change, default=[],
                        help="FIELD=VALUE[;FIELD=VALUE...]: one more run with these changes (repeat --set for "
                             "more runs)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    args = parser.parse_args(argv)
    names = [n for n in args.sequences.split(",") if n]
    unknown = [n for n in names if n not in SEQUENCES]
    if unknown or not names:
        parser.error(f"unknown sequence(s) {', '.join(unknown) or '(none)'} (valid: {', '.join(SEQUENCES)})")
    variants = [("defaults (baseline)", {})] + list(args.changes)
    for _, changes in variants:
        try:
            with_changes(PipelineSettings.from_presets(poses="vio_offline"), changes)
        except (ValueError, TypeError) as error:
            parser.error(str(error))
    print(f"# machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at start; --matcher {args.matcher}; all sequences SIMULATED")
    print("\n| sequence | settings | posed online | ATE mm | frames with depth | AbsRel | wrong | poses ms | total ms "
          "| keyframe updates | update CPU ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in names:
        for label, changes in variants:
            r = run(name, args.matcher, changes, args.cache)
            print(f"| {name} | {label} | {r['posed']} | {r['ate_mm']:.1f} | {r['depth']} | {r['abs_rel']:.4f} | "
                  f"{len(r['wrong'])} {', '.join(r['wrong'])} | {r['poses_ms']:.1f} | {r['total_ms']:.1f} | {r['updates']} | "
                  f"{r['update_cpu_ms']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
