"""Visual-inertial odometry (``--poses vio``): trajectory accuracy, scale, speed and dense depth,
with the sequences' poses withheld, against ``--poses gt`` in the same run.

For each bundled SIMULATED sample (``street``: default pairing; ``room``: ``--pairing indoor``,
evaluation cap 10 m, as in the README) two full runs (``run_sequence``, offline backfill on):

* ``gt`` -- the named baseline: the sequence's exact poses;
* ``vio`` -- the odometry from the images and the IMU alone (the poses are only read by the
  evaluation: tests/vio_depth/vio/test_vio_runs.py proves scrambled poses change nothing).

Columns: frames with metric depth, dense AbsRel (and the ratio to ``gt``), ATE RMSE (SE(3)
alignment, no scale correction) in metres and as a fraction of the distance travelled, RPE
over 1 m, the Sim(3) scale error (how far the metric scale is off), frames the odometry
posed when they were processed (the others -- its initialisation, the scale still
converging -- get their pose in the backward pass), and the odometry's own time per frame
(``poses`` stage: tracking, window updates; feature extraction excluded) as frames per second.

Points under ``--poses vio`` (issue 22), same samples, same run: ``--points vio`` (the
odometry's own landmarks with their marginal covariances, no second matching) against
``--points sfm`` (two-view pairs matched and triangulated again from the odometry's relative
poses; the ``vio`` row of the first table) and ``--points landmarks`` (a landmark window of
the points stage's own, the odometry's relative poses as between factors with their
covariance). Columns: frames written / processed, AbsRel and
oracle AbsRel over the frames written, wrong written frames (AbsRel > 2 x oracle + 0.02),
points per frame, the points stage's time per frame and the pipeline's time per frame
(``seconds``: image, features, odometry, points, fit, depth; the backward pass excluded).

With ``../shared/data/euroc_v101_static`` present (skipped otherwise): the **real** static
start -- the odometry on the 95 still frames of EuRoC V1_01 with the real 200 Hz IMU: when it
starts, its roll/pitch against the ground truth, and how far the still camera's estimate
wanders; then ``benchmarks/bench_imu.py``'s IMU-only propagation error on the whole real
IMU stream (the ``imu`` preset row: what the IMU alone gives, without images).

    python benchmarks/bench_vio.py                      # both samples + EuRoC (about 10 min on 2 cores)
    python benchmarks/bench_vio.py --samples room --no-euroc
    python benchmarks/bench_vio.py --samples street,room --no-euroc --backend process   # window inline vs worker

``--backend process``: only the ``--points vio`` table (klt + edge guard 0.1 unless ``--matcher``),
each sample with the odometry's window inline and in a worker process (``--lag-frames``, 6),
in the same run: frames written, wrong written frames (which), AbsRel and oracle AbsRel
(``--max-pending``: keyframes queued in the worker).
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EUROC = ROOT / ".." / "shared" / "data" / "euroc_v101_static"
SAMPLES = {"street": dict(pairing=None, max_depth=80.0), "room": dict(pairing="indoor", max_depth=10.0)}


def run_sample(name: str, poses: str, out: Path, points: str = "sfm", matcher: str | None = None,
               backend: str = "inline", lag_frames: int = 6, shared_confidence: float | None = None,
               max_pending: int = 1, provisional: bool = False):
    """``(RunSummary, frame records)`` of one full run (``matcher`` None: the default; klt with the
    edge guard 0.1, as the realtime benches; ``backend`` "process": the odometry's landmark window
    in a worker process, its updates taken over ``lag_frames`` later, up to ``max_pending`` keyframes
    queued, the frames meanwhile against the provisional window with ``provisional``)."""
    from dataclasses import replace

    from vio_depth import Pipeline, PipelineSettings, open_sequence
    from vio_depth.landmarks import WindowBackendSettings
    from vio_depth.run import RunSettings, read_frames_jsonl, run_sequence

    spec = SAMPLES[name]
    seq = open_sequence(ROOT / "sample_sequences" / name)
    # "vio" here: the odometry as this bench measures it, inline and sift unless changed below
    # (vio_offline; `--poses vio` is the camera-rate configuration since 2026-12-07: bench_realtime)
    preset = "vio_offline" if poses == "vio" else poses
    settings = PipelineSettings.from_presets(poses=preset, pairing=spec["pairing"], points=points, matcher=matcher)
    if matcher == "klt":  # its corners sit on depth edges (bench_realtime's klt rows do the same)
        settings = replace(settings, rescaler=replace(settings.rescaler, max_disparity_spread=0.1))
    if shared_confidence is not None:
        settings = replace(settings, rescaler=replace(settings.rescaler, shared_error_confidence=shared_confidence))
    if poses == "vio" and backend != "inline":
        settings = replace(settings, poses=replace(settings.poses, backend=WindowBackendSettings(
            backend, lag_frames, max_pending_keyframes=max_pending, provisional_landmarks=provisional)))
    summary = run_sequence(seq, Pipeline(settings, sequence=seq), out, RunSettings(max_eval_depth=spec["max_depth"]),
                           progress=False)
    return summary, read_frames_jsonl(out / "frames.jsonl")[1]


def wrong_frames(records) -> list[int]:
    """Frame indices written with AbsRel > 2 x the frame's oracle AbsRel + 0.02."""
    return [r["frame"] for r in records if r.get("alpha") is not None and r.get("abs_rel") is not None
            and r.get("oracle_abs_rel") is not None and r["abs_rel"] > 2 * r["oracle_abs_rel"] + 0.02]


def points_row(name: str, points: str, summary, records) -> str:
    """One row of the points comparison under ``--poses vio``."""
    m, oracle = summary.metrics[points], summary.metrics["oracle"]
    written = [r for r in records if r.get("alpha") is not None]
    wrong = sum(1 for r in written if r.get("abs_rel") is not None and r.get("oracle_abs_rel") is not None
                and r["abs_rel"] > 2 * r["oracle_abs_rel"] + 0.02)
    forward = [r for r in records if not r.get("backfilled")]
    t_points = np.mean([r["timings"].get("points", 0.0) for r in forward])
    t_frame = np.mean([r["seconds"] for r in forward])
    n_points = np.mean([r["triangulated_points"] for r in written]) if written else 0.0
    return (f"| {name} | {points} | {summary.frames_with_depth}/{summary.frames_processed} | {m['abs_rel']:.4f} "
            f"| {oracle['abs_rel']:.4f} | {wrong} | {n_points:.0f} | {1000 * t_points:.1f} | {1000 * t_frame:.0f} |")


def sample_rows(names) -> tuple[list[str], list[str]]:
    """Rows of the odometry table and of the points comparison."""
    rows, point_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            res = {p: run_sample(name, p, Path(tmp) / f"{name}_{p}") for p in ("gt", "vio")}
            point_rows.append(points_row(name, "sfm", *res["vio"]))
            for points in ("vio", "landmarks"):
                point_rows.append(points_row(name, points, *run_sample(name, "vio", Path(tmp) / f"{name}_vio_{points}",
                                                                       points=points)))
            gt_abs = res["gt"][0].metrics["sfm"]["abs_rel"]
            for p, (summary, records) in res.items():
                m = summary.metrics["sfm"]
                traj = summary.trajectory
                ate = traj["ate"]
                rpe = traj["rpe"]
                posed_live = sum(1 for r in records
                                 if r.get("pose_status") in ("tracking", "still") and not r.get("backfilled"))
                t_poses = [r["timings"]["poses"] for r in records if "poses" in r.get("timings", {})]
                fps = f"{1.0 / np.mean(t_poses):.1f}" if t_poses else "-"
                rows.append(
                    f"| {name} | {p} | {summary.frames_with_depth}/{summary.frames_processed} | {m['abs_rel']:.4f} "
                    f"| {m['abs_rel'] / gt_abs:.3f} | {ate['ate_m']['rmse']:.4f} | {ate['ate_fraction_of_path']:.2%} "
                    f"| {'-' if rpe is None else format(rpe['translation_m']['rmse'], '.4f')} "
                    f"| {ate['sim3_scale'] - 1:+.2%} | {posed_live if p == 'vio' else '-'} | {fps if p == 'vio' else '-'} |")
    return rows, point_rows


def backend_rows(names, matcher: str | None, backend: str, lag_frames: int,
                 shared_confidence: float | None = None, max_pending: int = 1, provisional: bool = False,
                 inline: bool = True) -> list[str]:
    """``--points vio`` with the odometry's window inline and in a worker process, same run: frames
    written, wrong written (and which), AbsRel and oracle AbsRel over the frames written."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for kind in ("inline", backend)[0 if inline else 1:]:
                summary, records = run_sample(name, "vio", Path(tmp) / f"{name}_{kind}", "vio", matcher, kind,
                                              lag_frames, shared_confidence, max_pending, provisional)
                m, oracle = summary.metrics["vio"], summary.metrics["oracle"]
                wrong = wrong_frames(records)
                label = "inline" if kind == "inline" else f"{kind}, lag {lag_frames}" + (
                    f", queue {max_pending}" if max_pending > 1 else "") + (", provisional" if provisional else "")
                rows.append(f"| {name} | {label} | {summary.frames_with_depth}/{summary.frames_processed} "
                            f"| {len(wrong)} {wrong if wrong else ''} | {m['abs_rel']:.4f} | {oracle['abs_rel']:.4f} |")
                print(rows[-1], flush=True)
    return rows


def euroc_static_start() -> list[str]:
    """The odometry on the real still EuRoC slice: when it starts, its roll/pitch against the
    ground truth, how far the still camera's estimate wanders."""
    from matchers import create_matcher
    from vio_depth.io import open_sequence
    from vio_depth.pipeline import POSE_PRESETS
    from vio_depth.vio import VioPoseSource

    seq = open_sequence(EUROC)
    matcher = create_matcher("sift")
    src = VioPoseSource(seq.imu, matcher, POSE_PRESETS["vio_offline"])  # inline, as this bench measures it
    out = [src.track(f, matcher.extract(f.image())) for f in seq]
    first = next((i for i, p in enumerate(out) if p.ok), None)
    if first is None:
        return [f"| EuRoC V1_01 still slice (real) | no start: {out[-1].reason} | - | - | 0/{len(seq)} |"]
    tilts = []
    for f in seq:
        T = src.world_pose(f)
        if T is not None and f.T_w_c is not None:
            up_e, up_g = T[:3, :3].T @ [0, 0, 1], f.T_w_c[:3, :3].T @ [0, 0, 1]
            tilts.append(np.degrees(np.arccos(np.clip(up_e @ up_g, -1, 1))))
    posed = [T for T in (src.world_pose(f) for f in seq) if T is not None]
    gt = [f.T_w_c for f in seq if f.T_w_c is not None]
    moves = np.linalg.norm(np.stack([T[:3, 3] for T in posed]) - posed[0][:3, 3], axis=1)
    gt_moves = np.linalg.norm(np.stack([T[:3, 3] for T in gt]) - gt[0][:3, 3], axis=1)
    return [f"| EuRoC V1_01 still slice (real images and IMU) | {out[first].reason or out[first].status} at frame "
            f"{first} ({seq[first].timestamp - seq[0].timestamp:.2f} s) | {np.median(tilts):.2f} deg median "
            f"(max {np.max(tilts):.2f}) | {moves.max() * 100:.1f} cm (ground truth: {gt_moves.max() * 100:.1f} cm) "
            f"| {len(posed)}/{len(seq)} |"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", nargs="*", default=list(SAMPLES))
    parser.add_argument("--no-euroc", action="store_true")
    parser.add_argument("--backend", default=None, help="e.g. 'process': only the --points vio table, the "
                        "odometry's window inline and in a worker process (klt matcher unless --matcher)")
    parser.add_argument("--lag-frames", type=int, default=6, help="with --backend: frames until an update is taken")
    parser.add_argument("--max-pending", type=int, default=1,
                        help="with --backend: keyframes queued in the worker at most (1: none while one is pending)")
    parser.add_argument("--provisional", action="store_true",
                        help="with --backend: frames meanwhile against the window extended by the pending keyframe")
    parser.add_argument("--no-inline", action="store_true", help="with --backend: skip the inline rows")
    parser.add_argument("--shared-error-confidence", type=float, default=None,
                        help="with --backend: the rescaler's shared_error_confidence (default: off)")
    parser.add_argument("--matcher", default=None, help="matcher preset (default: the pipeline's; klt with --backend)")
    args = parser.parse_args(argv)
    args.samples = [n for arg in args.samples for n in arg.split(",") if n]  # "street,room" or "street room"
    unknown = [n for n in args.samples if n not in SAMPLES]
    if unknown:
        parser.error(f"unknown sample(s) {', '.join(unknown)} (valid: {', '.join(SAMPLES)})")
    print(f"# machine: {platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, "
          f"numpy {np.__version__}; timings on a shared machine are indicative only")
    if args.backend is not None:
        matcher = args.matcher or "klt"
        print(f"\n--points vio, --matcher {matcher}{' (edge guard 0.1)' if matcher == 'klt' else ''}, offline "
              "(backward pass); wrong: AbsRel > 2 x the frame's oracle + 0.02\n")
        print("| sample (SIMULATED) | window | frames written | wrong written (frames) | AbsRel | oracle AbsRel |")
        print("|---" * 6 + "|")
        if args.shared_error_confidence is not None:
            print(f"(rescaler: shared_error_confidence {args.shared_error_confidence})\n")
        backend_rows(args.samples, matcher, args.backend, args.lag_frames, args.shared_error_confidence,
                     args.max_pending, args.provisional, not args.no_inline)
        return 0
    if args.samples:
        print("\n| sample (SIMULATED) | poses | frames with depth | AbsRel | / gt | ATE m | ATE / path | RPE 1 m "
              "| scale error | posed live | odometry fps |")
        print("|---" * 11 + "|")
        rows, point_rows = sample_rows(args.samples)
        for row in rows:
            print(row, flush=True)
        print("\nPoints under --poses vio: the odometry's landmarks (vio) against two-view pairs (sfm)\n")
        print("| sample (SIMULATED) | --points | frames written | AbsRel | oracle AbsRel | wrong written "
              "| points/frame | points stage ms/frame | pipeline ms/frame |")
        print("|---" * 9 + "|")
        for row in point_rows:
            print(row, flush=True)
    if not args.no_euroc:
        if not EUROC.is_dir():
            print(f"\n(EuRoC slice not present at {EUROC}: skipped)")
        else:
            print("\n| sequence | start | roll/pitch error vs ground truth | largest move of the still camera "
                  "| posed frames |")
            print("|---|---|---|---|---|")
            for row in euroc_static_start():
                print(row, flush=True)
            print("\nIMU-only propagation on the whole real EuRoC V1_01 stream (benchmarks/bench_imu.py, preset imu):")
            sys.path.insert(0, str(ROOT / "benchmarks"))
            import bench_imu

            bench_imu.SETTINGS = {"imu": bench_imu.SETTINGS["imu"]}
            bench_imu.main(["--sequences", "euroc"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
