"""Benchmark: multi-view landmarks (gtsam window) against the two-view pipeline, same rescaler.

For each dataset both paths process the same frames in order, with SIFT, the sequence's
poses, RANSAC seed 0 and the CLI's rescaler defaults (fallbacks and temporal filter on):

* ``two-view`` (the named baseline): ``vio-depth run --points sfm`` (pairing preset below,
  offline backfill on), through :func:`vio_depth.run.run_sequence`;
* ``landmarks``: ``vio-depth run --points landmarks`` (default
  :class:`~vio_depth.landmarks.LandmarkSettings`; the pose prior is the preset of the
  sequence's kind of poses, ``Sequence.pose_kind``; no pairing preset), the same runner;
* ``landmarks-isam2`` / ``landmarks-batch`` (only when asked for with ``--paths``): the same
  with ``LandmarkSettings.solver`` set (``isam2``, the incremental window of
  :mod:`vio_depth.landmarks.isam`, is the default since 2026-12-06; ``--baseline-rev`` runs
  the window of an earlier revision);
* ``landmarks-process`` (only when asked for): the window in a worker process
  (``[landmarks_backend] kind = "process"``, ``lag_frames`` = ``--process-lag``, default 2): a
  keyframe's frame no longer waits for the window's update. Its ``pts CPU ms`` and ``run CPU
  s/fr`` leave the worker's CPU out: compare its wall-time columns;
* ``landmarks-provisional`` (only when asked for): the same with ``provisional_landmarks``: the
  frames of the lag are queried against the window extended by the pending keyframe.

Datasets (a missing folder is skipped; ``--data`` points at the shared data folder):

========  ==========================================  ========  =============  ============  =========
name      folder                                      frames    two-view pair  pose prior    max depth
========  ==========================================  ========  =============  ============  =========
7scenes   DATA/7scenes_redkitchen (real, KinectFusion)  0-299    indoor         kinectfusion  10 m
kitti     DATA/kitti_tiny (real, OXTS)                  0-6      kitti          ins           80 m
street    sample_sequences/street (rendered)            all 130  kitti          exact         80 m
room      sample_sequences/room (rendered)              all 120  indoor         exact         10 m
========  ==========================================  ========  =============  ============  =========

**Every dense figure uses SIMULATED disparity**: 7-Scenes and KITTI get
``--disparity simulated`` (seed 0), the samples their own simulated maps. Point errors are real
on 7-Scenes and KITTI (real images and poses against Kinect / LiDAR depth).

Columns: ``pt med`` / ``pt p90``: medians over frames of each frame's median / 90th
percentile of ``|z - z_gt| / z_gt`` of the points fed to the fit
(:func:`vio_depth.evaluation.point_depth_errors`, 5x5 window-median reference);
``bias``: median over frames of the signed median; ``pts/fr``: median points per frame;
``AbsRel`` / ``delta1``: frame-averaged dense metrics over the frames with depth
(:func:`vio_depth.evaluation.compute_metrics`), ``oracle`` the least-squares fit of the same
disparity on the same frames; ``x oracle`` their ratio; ``depth``: frames given depth /
frames processed; ``bad ok``: frames with status ok whose AbsRel exceeds 2 x their own
oracle + 0.02.

``s/fr``: the run's median pipeline seconds per frame; ``pts ms``: the points stage's mean
milliseconds per frame (matching, the landmark window or the two-view pairs, triangulation:
what the two paths do differently).

``s/fr mean``: the run's mean pipeline seconds per frame (keyframe frames, which cost the
landmark path most, weigh in by their share instead of falling on one side of the median).
``pts CPU ms``: the points stage's CPU per frame in its calling thread; ``run CPU s/fr``: the
whole run's process CPU seconds per frame (every thread, evaluation and writing included):
both move much less with other jobs on the machine than wall time.

``--guided``: pose-guided matching (``--guided-matching``, :mod:`matchers.guided`) in both paths:
the two-view pairs and the window's keyframes are matched inside the epipolar band of the pose
known before matching (SIFT only).

Run: ``python benchmarks/bench_landmarks.py [--datasets 7scenes,kitti,street,room]
[--frames N] [--data DIR] [--paths two-view,landmarks] [--matcher sift|klt] [--edge-guard F] [--guided]``
(``--matcher klt --edge-guard 0.1``: the KLT front end as ``vio-depth run --matcher klt
--edge-guard 0.1``). Seconds per frame are printed: compare them only within one run.

Same-machine A/B against a baseline revision: ``--baseline-rev REV [--repeats N]`` runs the
whole selection with ``REV``'s code (a temporary git worktree, this script run in a subprocess
with that checkout's packages first on the path) and with this checkout's, alternating, ``N``
times each, and prints one line per run and path (points stage ms, s/fr median and mean,
AbsRel, frames with depth, bad ok; and CPU time: the points stage's, in its calling thread, and the whole run's, every
thread, evaluation and writing included -- figures that other jobs on a shared machine inflate
much less than wall time) and the landmark / two-view ratios of each run.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
# run as a script from anywhere: this checkout's packages first -- or, for one side of an A/B
# run (--code DIR, internal), those of the checkout DIR
CODE = Path(sys.argv[sys.argv.index("--code") + 1]).resolve() if "--code" in sys.argv[:-1] else REPO
if str(CODE) not in sys.path:
    sys.path.insert(0, str(CODE))

from vio_depth import Pipeline, PipelineSettings, open_sequence  # noqa: E402
from vio_depth.run import RunSettings, read_frames_jsonl, run_sequence  # noqa: E402


@dataclass(frozen=True)
class Dataset:
    name: str
    path: str  # relative to --data ("DATA/...") or to the repository
    pairing: str
    disparity: str  # "simulated" or "sequence"
    max_depth: float
    frames: int | None = None

    def folder(self, data: Path) -> Path:
        """Where the dataset is: ``DATA/...`` under the shared data folder ``data``, else in the repository."""
        return (data / self.path[5:]) if self.path.startswith("DATA/") else REPO / self.path


DATASETS = {d.name: d for d in (
    Dataset("7scenes", "DATA/7scenes_redkitchen", "indoor", "simulated", 10.0, 300),
    Dataset("kitti", "DATA/kitti_tiny", "kitti", "simulated", 80.0),
    Dataset("street", "sample_sequences/street", "kitti", "sequence", 80.0),
    Dataset("room", "sample_sequences/room", "indoor", "sequence", 10.0),
)}
PATHS = {"two-view": "sfm", "landmarks": "landmarks", "landmarks-isam2": "landmarks", "landmarks-batch": "landmarks",
         "landmarks-process": "landmarks", "landmarks-provisional": "landmarks"}
#: landmark settings of a path beyond its points preset (``landmarks-isam2`` / ``-batch``: that solver)
PATH_LANDMARKS = {"landmarks-isam2": {"solver": "isam2"}, "landmarks-batch": {"solver": "batch"}}
#: where a path's window runs (``landmarks-process``: in a worker process, ``[landmarks_backend]``;
#: ``lag_frames`` from ``--process-lag``)
PATH_BACKEND = {"landmarks-process": {"kind": "process"},
                "landmarks-provisional": {"kind": "process", "provisional_landmarks": True}}


def run_path(ds: Dataset, sequence, n: int, path: str, out: Path, matcher: str = "sift",
             edge_guard: float | None = None, guided: bool = False, process_lag: int = 2) -> tuple[dict, list[dict]]:
    """One path over the first ``n`` frames: ``(metrics.json, frame records)``; ``matcher`` a
    matcher preset, ``edge_guard`` the rescaler's ``max_disparity_spread`` (``--edge-guard``) or None,
    ``guided``: pose-guided matching (``--guided-matching``) in both paths; ``process_lag``: the
    ``lag_frames`` of ``landmarks-process``."""
    settings = PipelineSettings.from_presets(points=PATHS[path], pairing=ds.pairing, matcher=matcher)
    overrides = {"disparity": {"source": ds.disparity}}
    if guided:
        overrides["matcher"] = {"guided": {"enabled": True}}
    if path in PATH_LANDMARKS:
        overrides["landmarks"] = PATH_LANDMARKS[path]
    if path in PATH_BACKEND:
        overrides["landmarks_backend"] = {**PATH_BACKEND[path], "lag_frames": process_lag}
    if edge_guard is not None:
        overrides["rescaler"] = {"max_disparity_spread": edge_guard}
    settings = PipelineSettings.from_dict(overrides, settings)
    pipeline = Pipeline(settings, sequence=sequence)
    # CPU seconds of the points stage (the calling thread's: the window's gtsam and numpy run
    # there) and of the whole run (every thread): robust to other jobs on the machine
    stage, cpu = pipeline.points.process, []

    def timed(*args, **kwargs):
        start = time.thread_time()
        try:
            return stage(*args, **kwargs)
        finally:
            cpu.append(time.thread_time() - start)

    pipeline.points.process = timed
    start = time.process_time()
    run_sequence(sequence, pipeline, out, RunSettings(max_frames=n, max_eval_depth=ds.max_depth), progress=False)
    LAST_CPU.update(points_ms=1000.0 * float(np.mean(cpu)) if cpu else float("nan"),
                    run_s=(time.process_time() - start) / max(n, 1))
    return json.loads((out / "metrics.json").read_text()), read_frames_jsonl(out / "frames.jsonl")[1]


#: CPU figures of the last :func:`run_path`: ``points_ms`` (points stage, calling thread, mean per
#: call) and ``run_s`` (the whole run's process CPU seconds, evaluation and writing included, per frame)
LAST_CPU: dict = {}


def _median(values) -> float:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else float("nan")


def _mean_ms(values) -> float:
    values = [v for v in values if v is not None]
    return 1000.0 * float(np.mean(values)) if values else float("nan")


def _bad_frames(frames: list[dict]) -> list[int]:
    """Frames with status ok whose AbsRel exceeds 2 x their own oracle + 0.02 (``bad ok``)."""
    return [f["frame"] for f in frames if f["status"] == "ok" and f.get("abs_rel") is not None
            and f.get("oracle_abs_rel") is not None and f["abs_rel"] > 2 * f["oracle_abs_rel"] + 0.02]


def format_row(path: str, metrics: dict, frames: list[dict]) -> str:
    row = metrics["metrics"].get(PATHS[path], {})
    oracle = metrics["metrics"].get("oracle", {})
    bad = _bad_frames(frames)
    ratio = row.get("abs_rel", float("nan")) / oracle.get("abs_rel", float("nan")) if oracle else float("nan")
    statuses = ", ".join(f"{k} {v}" for k, v in sorted(metrics["status_counts"].items()))
    line = (f"{path:10s} {_median(f.get('points_rel_err_median') for f in frames):7.4f} "
            f"{_median(f.get('points_rel_err_p90') for f in frames):7.4f} "
            f"{_median(f.get('points_rel_err_bias') for f in frames):+7.4f} "
            f"{_median(f['triangulated_points'] for f in frames):6.0f} {row.get('abs_rel', float('nan')):7.4f} "
            f"{row.get('delta1', float('nan')):7.4f} {oracle.get('abs_rel', float('nan')):7.4f} {ratio:8.2f} "
            f"{metrics['frames_with_depth']:4d}/{metrics['frames_processed']:<4d} {len(bad):5d} "
            f"{_median(f['seconds'] for f in frames):6.3f} "
            f"{_mean_ms(f.get('timings', {}).get('points') for f in frames):7.1f} "
            f"{_mean_ms(f['seconds'] for f in frames) / 1000:10.3f} "
            f"{LAST_CPU.get('points_ms', float('nan')):10.1f} {LAST_CPU.get('run_s', float('nan')):12.3f}")
    line += f"\n  {path} statuses: {statuses}"
    if bad:
        line += f"\n  {path} ok frames above 2 x oracle + 0.02: {bad[:40]}" + (" ..." if len(bad) > 40 else "")
    return line


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default="7scenes,kitti,street,room")
    parser.add_argument("--paths", default="two-view,landmarks")
    parser.add_argument("--frames", type=int, default=None, help="cap every dataset at N frames")
    parser.add_argument("--data", type=Path, default=REPO / ".." / "shared" / "data")
    parser.add_argument("--matcher", default="sift", help="matcher preset (sift, klt, ...)")
    parser.add_argument("--edge-guard", type=float, default=None, metavar="F",
                        help="the rescaler's max_disparity_spread, as vio-depth run --edge-guard")
    parser.add_argument("--guided", action="store_true",
                        help="pose-guided matching in both paths (--guided-matching; SIFT only)")
    parser.add_argument("--process-lag", type=int, default=2, metavar="N",
                        help="lag_frames of the landmarks-process / -provisional paths (the window in a worker process)")
    parser.add_argument("--baseline-rev", default=None, help="A/B: also run this revision's code, alternating")
    parser.add_argument("--repeats", type=int, default=1, help="A/B: runs of each side")
    parser.add_argument("--code", type=Path, default=None, help=argparse.SUPPRESS)  # internal: one A/B side
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # internal: one A/B side
    args = parser.parse_args(argv)
    if args.baseline_rev is not None:
        return ab_main(args)
    if args.json:
        print(json.dumps(summaries(args)))
        return 0
    print(f"bench_landmarks (matcher {args.matcher}, edge guard {args.edge_guard}, guided {args.guided}), "
          f"{datetime.date.today()}, "
          f"{platform.machine()}, {os.cpu_count()} CPU cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, load average {os.getloadavg()[0]:.1f}")
    print("NOTE: dense figures use SIMULATED disparity on every dataset (see the module docstring)")
    head = (f"{'path':10s} {'pt med':>7s} {'pt p90':>7s} {'bias':>7s} {'pts/fr':>6s} {'AbsRel':>7s} "
            f"{'delta1':>7s} {'oracle':>7s} {'x oracle':>8s} {'depth':>9s} {'bad ok':>6s} {'s/fr':>6s} {'pts ms':>7s} {'s/fr mean':>10s} "
            f"{'pts CPU ms':>10s} {'run CPU s/fr':>12s}")
    for name in args.datasets.split(","):
        ds = DATASETS[name]
        folder = ds.folder(args.data)
        if not folder.exists():
            print(f"\n{name}: {folder} missing, skipped")
            continue
        sequence = open_sequence(folder)
        n = min(len(sequence), ds.frames or len(sequence), args.frames or len(sequence))
        print(f"\n{name}: {folder.name}, frames 0-{n - 1}, max depth {ds.max_depth:g} m, two-view pairing "
              f"'{ds.pairing}', landmark pose prior '{sequence.pose_kind}'\n{head}")
        with tempfile.TemporaryDirectory() as tmp:
            for path in args.paths.split(","):
                metrics, frames = run_path(ds, sequence, n, path, Path(tmp) / path, args.matcher, args.edge_guard,
                                           args.guided, args.process_lag)
                print(format_row(path, metrics, frames), flush=True)
    return 0


def summaries(args) -> list[dict]:
    """One A/B side: per dataset and path, the points stage's mean ms, s/fr median and mean, AbsRel."""
    out = []
    for name in args.datasets.split(","):
        ds = DATASETS[name]
        folder = ds.folder(args.data)
        if not folder.exists():
            continue
        sequence = open_sequence(folder)
        n = min(len(sequence), ds.frames or len(sequence), args.frames or len(sequence))
        with tempfile.TemporaryDirectory() as tmp:
            for path in args.paths.split(","):
                metrics, frames = run_path(ds, sequence, n, path, Path(tmp) / path, args.matcher, args.edge_guard,
                                           args.guided, args.process_lag)
                out.append({"dataset": name, "path": path, "frames": n,
                            "pts_ms": _mean_ms(f.get("timings", {}).get("points") for f in frames),
                            "s_median": _median(f["seconds"] for f in frames),
                            "s_mean": _mean_ms(f["seconds"] for f in frames) / 1000.0,
                            "abs_rel": metrics["metrics"].get(PATHS[path], {}).get("abs_rel", float("nan")),
                            "pts_cpu_ms": LAST_CPU["points_ms"], "run_cpu_s": LAST_CPU["run_s"],
                            "depth": f"{metrics['frames_with_depth']}/{metrics['frames_processed']}",
                            "bad": len(_bad_frames(frames))})
    return out


def ab_main(args) -> int:
    """Alternate runs of the baseline revision's code and this checkout's (module docstring)."""
    import subprocess

    sys.path.insert(0, str(REPO / "benchmarks"))
    from baseline_checkout import baseline_checkout

    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    print(f"bench_landmarks A/B (matcher {args.matcher}, edge guard {args.edge_guard}, guided {args.guided}), "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, "
          f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}; baseline {args.baseline_rev}, "
          f"this checkout at {head} (plus any uncommitted changes)")
    print("NOTE: dense figures use SIMULATED disparity on every dataset (see the module docstring)")
    passed = ["--datasets", args.datasets, "--paths", args.paths, "--data", str(args.data), "--matcher", args.matcher,
              "--json"] + (["--frames", str(args.frames)] if args.frames else []) \
        + (["--edge-guard", str(args.edge_guard)] if args.edge_guard is not None else []) \
        + (["--guided"] if args.guided else []) \
        + (["--process-lag", str(args.process_lag)] if "landmarks-p" in args.paths else [])
    rows = []
    with tempfile.TemporaryDirectory() as tmp, baseline_checkout(args.baseline_rev, Path(tmp) / "baseline") as base:
        for k in range(args.repeats):
            for side, code in ((f"baseline {args.baseline_rev}", base), ("this checkout", REPO)):
                res = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--code", str(code), *passed],
                                     capture_output=True, text=True, check=True)
                for r in json.loads(res.stdout.strip().splitlines()[-1]):
                    rows.append((side, k + 1, r))
                    print(f"  {side} run {k + 1} {r['dataset']} {r['path']}: pts {r['pts_ms']:.1f} ms (CPU "
                          f"{r['pts_cpu_ms']:.1f}), s/fr {r['s_median']:.3f} / mean {r['s_mean']:.3f}, run CPU "
                          f"{r['run_cpu_s']:.3f} s/fr, AbsRel {r['abs_rel']:.4f}, depth {r['depth']}, "
                          f"bad ok {r.get('bad', '-')}", flush=True)
    print("\n| dataset | code | run | two-view pts ms (CPU) | landmarks pts ms (CPU) | pts ratio (CPU) | two-view "
          "s/fr median / mean | landmarks s/fr median / mean | whole ratio median / mean | run CPU ratio "
          "| two-view AbsRel | landmarks AbsRel |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for side, k, r in rows:
        if r["path"] != "landmarks":
            continue
        tv = next((q for s_, k_, q in rows if s_ == side and k_ == k and q["dataset"] == r["dataset"]
                   and q["path"] == "two-view"), None)
        if tv is None:
            print(f"| {r['dataset']} | {side} | {k} | - | {r['pts_ms']:.1f} ({r['pts_cpu_ms']:.1f}) | - | - | "
                  f"{r['s_median']:.3f} / {r['s_mean']:.3f} | - | - | - | {r['abs_rel']:.4f} |")
            continue
        print(f"| {r['dataset']} | {side} | {k} | {tv['pts_ms']:.1f} ({tv['pts_cpu_ms']:.1f}) | {r['pts_ms']:.1f} "
              f"({r['pts_cpu_ms']:.1f}) | {r['pts_ms'] / tv['pts_ms']:.2f} x ({r['pts_cpu_ms'] / tv['pts_cpu_ms']:.2f} x) "
              f"| {tv['s_median']:.3f} / {tv['s_mean']:.3f} | {r['s_median']:.3f} / {r['s_mean']:.3f} | "
              f"{r['s_median'] / tv['s_median']:.2f} / {r['s_mean'] / tv['s_mean']:.2f} x | "
              f"{r['run_cpu_s'] / tv['run_cpu_s']:.2f} x | {tv['abs_rel']:.4f} | {r['abs_rel']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
