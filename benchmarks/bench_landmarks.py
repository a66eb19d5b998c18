"""Benchmark: multi-view landmarks (gtsam window) against the two-view pipeline, same rescaler.

For each dataset both paths process the same frames in order, with SIFT, the sequence's
poses, RANSAC seed 0 and the CLI's rescaler defaults (fallbacks and temporal filter on):

* ``two-view`` (the named baseline): :class:`vio_depth.pipeline.Pipeline` through
  :func:`vio_depth.run.run_sequence`, exactly as ``vio-depth run`` (pairing preset below,
  offline backfill on);
* ``landmarks``: :class:`vio_depth.landmarks.LandmarkEstimator` (default
  :class:`LandmarkSettings` with the dataset kind's pose-prior preset) gives each frame its
  landmark points (uv, depth, sigma), which go through the same
  :class:`vio_depth.rescale.Rescaler`; the leading frames without depth get the same kind
  of offline backward pass as ``run_sequence``'s backfill (a fresh estimator and rescaler
  run backwards from ``2 x window_keyframes`` frames past them).

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
:class:`vio_depth.simulate.gt_disparity.GroundTruthSimulatedDisparity` (seed 0, the CLI's
``--disparity simulated``), the samples their own simulated maps. Point errors are real
on 7-Scenes and KITTI (real images and poses against Kinect / LiDAR depth).

Columns: ``pt med`` / ``pt p90``: medians over frames of each frame's median / 90th
percentile of ``|z - z_gt| / z_gt`` of the points fed to the fit
(:func:`vio_depth.point_accuracy.point_depth_errors`, 5x5 window-median reference);
``bias``: median over frames of the signed median; ``pts/fr``: median points per frame;
``AbsRel`` / ``delta1``: frame-averaged dense metrics over the frames with depth
(:func:`vio_depth.metrics.compute_metrics`), ``oracle`` the least-squares fit of the same
disparity on the same frames; ``x oracle`` their ratio; ``depth``: frames given depth /
frames processed; ``bad ok``: frames with status ok whose AbsRel exceeds 2 x their own
oracle + 0.02.

Run: ``python benchmarks/bench_landmarks.py [--datasets 7scenes,kitti,street,room]
[--frames N] [--data DIR] [--cache DIR] [--paths two-view,landmarks]``. ``--cache`` keeps
each frame's SIFT features of the landmark path on disk (re-runs skip extraction).
Timings are not reported (shared, loaded machine).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run as a script from anywhere: this checkout's packages first
    sys.path.insert(0, str(REPO))


@dataclass(frozen=True)
class Dataset:
    name: str
    path: str  # relative to --data ("DATA/...") or to the repository
    pairing: str
    pose_prior: str
    disparity: str  # "gt_simulated" or "sequence"
    max_depth: float
    frames: int | None = None


DATASETS = {d.name: d for d in (
    Dataset("7scenes", "DATA/7scenes_redkitchen", "indoor", "kinectfusion", "gt_simulated", 10.0, 300),
    Dataset("kitti", "DATA/kitti_tiny", "kitti", "ins", "gt_simulated", 80.0),
    Dataset("street", "sample_sequences/street", "kitti", "exact", "sequence", 80.0),
    Dataset("room", "sample_sequences/room", "indoor", "exact", "sequence", 10.0),
)}


@dataclass
class PathResult:
    """Per-frame outcomes of one path on one dataset."""

    frames: int = 0
    with_depth: int = 0
    metrics: list = field(default_factory=list)  # DepthMetrics of frames with depth
    oracle: list = field(default_factory=list)  # DepthMetrics of the oracle on the same frames
    point_median: list = field(default_factory=list)
    point_p90: list = field(default_factory=list)
    point_bias: list = field(default_factory=list)
    point_count: list = field(default_factory=list)
    bad_ok: list = field(default_factory=list)  # frame indices
    statuses: dict = field(default_factory=dict)


def _disparity(ds: Dataset, sequence):
    from vio_depth.disparity import SequenceDisparity
    from vio_depth.simulate.gt_disparity import GroundTruthSimulatedDisparity

    return GroundTruthSimulatedDisparity(seed=0) if ds.disparity == "gt_simulated" else SequenceDisparity(sequence)


def run_two_view(ds: Dataset, sequence, n: int) -> PathResult:
    """The existing pipeline, as ``vio-depth run`` runs it; per-frame figures from frames.jsonl."""
    import json

    from vio_depth.keyframes import pairing_preset
    from vio_depth.pipeline import Pipeline, PipelineSettings
    from vio_depth.poses import GroundTruthPoses
    from vio_depth.rescale import RescalerSettings
    from vio_depth.run import run_sequence

    settings = PipelineSettings(pairing=pairing_preset(ds.pairing), rescaler=RescalerSettings.default(seed=0))
    pipeline = Pipeline(settings, GroundTruthPoses(), _disparity(ds, sequence))
    out = PathResult(frames=n)
    with tempfile.TemporaryDirectory() as tmp:
        run_sequence(sequence, pipeline, tmp, max_frames=n, max_eval_depth=ds.max_depth, progress=False)
        rows = [json.loads(line) for line in (Path(tmp) / "frames.jsonl").read_text().splitlines()]
    for r in rows:
        out.statuses[r["status"]] = out.statuses.get(r["status"], 0) + 1
        if r.get("abs_rel") is not None:
            out.with_depth += 1
            out.metrics.append((r["abs_rel"], r["delta1"]))
            out.oracle.append(r.get("oracle_abs_rel"))
            if r["status"] == "ok" and r.get("oracle_abs_rel") is not None and \
                    r["abs_rel"] > 2 * r["oracle_abs_rel"] + 0.02:
                out.bad_ok.append(r["frame"])
        if r.get("points_rel_err_median") is not None:
            out.point_median.append(r["points_rel_err_median"])
            out.point_p90.append(r["points_rel_err_p90"])
            out.point_count.append(r["points_evaluated"])
    return out


class _FeatureCache:
    def __init__(self, matcher, folder: Path | None):
        self.matcher = matcher
        self.folder = folder
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)

    def __call__(self, frame):
        from matchers.base import Features

        path = None if self.folder is None else self.folder / f"{frame.index:06d}.npz"
        if path is not None and path.is_file():
            z = np.load(path)
            return Features(z["kp"], z["desc"], z["sc"], tuple(int(v) for v in z["size"]))
        f = self.matcher.extract(frame.image())
        if path is not None:
            np.savez(path, kp=f.keypoints, desc=f.descriptors, sc=f.scores, size=np.array(f.image_size))
        return f


def _landmark_pass(ds: Dataset, sequence, order: list[int], features, disparity, settings, matcher):
    """Run a fresh estimator + rescaler over ``order``; {index: (frame result tuple)}."""
    from vio_depth.landmarks import LandmarkEstimator
    from vio_depth.rescale import Rescaler, RescalerSettings, sample_bilinear

    est = LandmarkEstimator(settings, matcher)
    rescaler = Rescaler(RescalerSettings.default(seed=0))
    out = {}
    for k, i in enumerate(order):
        frame = sequence[i]
        disp = disparity(frame)
        res = est.process(k, float(k), frame.camera, frame.T_w_c, features(frame))
        p = res.points
        if disp is None:
            out[i] = (frame, None, None, p, None)
            continue
        d, inside = sample_bilinear(disp, p.uv)
        r = rescaler.update(d[inside], p.depth[inside], p.sigma_depth[inside], None, disparity_map=disp)
        out[i] = (frame, disp, r, p, inside)
    return out


def run_landmarks(ds: Dataset, sequence, n: int, cache: Path | None) -> PathResult:
    from matchers import create_matcher
    from vio_depth.landmarks import LandmarkSettings
    from vio_depth.metrics import compute_metrics, oracle_fit
    from vio_depth.point_accuracy import point_depth_errors
    from vio_depth.rescale import metric_depth

    matcher = create_matcher("sift")
    features = _FeatureCache(matcher, None if cache is None else cache / ds.name)
    disparity = _disparity(ds, sequence)
    settings = LandmarkSettings.for_poses(ds.pose_prior)
    results = _landmark_pass(ds, sequence, list(range(n)), features, disparity, settings, matcher)
    first = next((i for i in range(n) if results[i][2] is not None and results[i][2].has_depth), None)
    if first:  # offline backfill of the leading frames, as run_sequence does
        last = min(n - 1, first + 2 * settings.window_keyframes)
        back = _landmark_pass(ds, sequence, list(range(last, -1, -1)), features, disparity, settings, matcher)
        for i in range(first):
            if back[i][2] is not None and back[i][2].has_depth:
                results[i] = back[i]
    out = PathResult(frames=n)
    for i in range(n):
        frame, disp, r, p, inside = results[i]
        status = "no_disparity" if r is None else r.frame_status.value
        out.statuses[status] = out.statuses.get(status, 0) + 1
        gt = frame.gt_depth()
        if r is not None and len(p) and inside.any():
            acc = point_depth_errors(p.uv[inside], p.depth[inside], gt)
            if acc.count:
                out.point_median.append(acc.median)
                out.point_p90.append(acc.p90)
                out.point_bias.append(acc.bias)
                out.point_count.append(acc.count)
        if r is None or not r.has_depth:
            continue
        out.with_depth += 1
        m = compute_metrics(r.metric_depth(disp), gt, min_depth=1e-3, max_depth=ds.max_depth)
        ofit = oracle_fit(disp, gt, min_depth=1e-3, max_depth=ds.max_depth)
        o = compute_metrics(metric_depth(disp, ofit), gt, min_depth=1e-3, max_depth=ds.max_depth) if ofit.ok else None
        out.metrics.append((m.abs_rel, m.delta1))
        out.oracle.append(None if o is None else o.abs_rel)
        if status == "ok" and o is not None and m.abs_rel > 2 * o.abs_rel + 0.02:
            out.bad_ok.append(i)
    return out


def _f(x, spec=".4f"):
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def format_rows(ds: Dataset, n: int, rows: dict[str, PathResult]) -> str:
    head = (f"{'path':10s} {'pt med':>7s} {'pt p90':>7s} {'bias':>7s} {'pts/fr':>6s} {'AbsRel':>7s} {'delta1':>7s} "
            f"{'oracle':>7s} {'x oracle':>8s} {'depth':>9s} {'bad ok':>6s}")
    lines = [head]
    for name, r in rows.items():
        absrel = np.mean([a for a, _ in r.metrics]) if r.metrics else float("nan")
        delta1 = np.mean([d for _, d in r.metrics]) if r.metrics else float("nan")
        orc = [o for o in r.oracle if o is not None]
        oracle = np.mean(orc) if orc else float("nan")
        lines.append(
            f"{name:10s} {_f(np.median(r.point_median) if r.point_median else None):>7s} "
            f"{_f(np.median(r.point_p90) if r.point_p90 else None):>7s} "
            f"{_f(np.median(r.point_bias) if r.point_bias else None, '+.4f'):>7s} "
            f"{_f(np.median(r.point_count) if r.point_count else None, '.0f'):>6s} {_f(absrel):>7s} {_f(delta1):>7s} "
            f"{_f(oracle):>7s} {_f(absrel / oracle if orc else None, '.2f'):>8s} "
            f"{f'{r.with_depth}/{r.frames}':>9s} {len(r.bad_ok):>6d}")
    for name, r in rows.items():
        lines.append(f"  {name} statuses: " + ", ".join(f"{k} {v}" for k, v in sorted(r.statuses.items())))
        if r.bad_ok:
            lines.append(f"  {name} ok frames above 2 x oracle + 0.02: {r.bad_ok[:40]}{' ...' if len(r.bad_ok) > 40 else ''}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default="7scenes,kitti,street,room")
    parser.add_argument("--paths", default="two-view,landmarks")
    parser.add_argument("--frames", type=int, default=None, help="cap every dataset at N frames")
    parser.add_argument("--data", type=Path, default=REPO / ".." / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args(argv)
    from vio_depth.io import open_sequence

    print(f"bench_landmarks, {datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPU cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    print("NOTE: dense figures use SIMULATED disparity on every dataset (see the module docstring)")
    status = 0
    for name in args.datasets.split(","):
        ds = DATASETS[name]
        folder = args.data / ds.path[5:] if ds.path.startswith("DATA/") else REPO / ds.path
        if not folder.is_dir():
            print(f"\n{name}: {folder} missing, skipped")
            continue
        sequence = open_sequence(folder)
        n = len(sequence) if ds.frames is None else min(ds.frames, len(sequence))
        n = n if args.frames is None else min(n, args.frames)
        rows = {}
        for path in args.paths.split(","):
            try:
                rows[path] = (run_two_view(ds, sequence, n) if path == "two-view"
                              else run_landmarks(ds, sequence, n, args.cache))
            except Exception as e:  # report and go on with the other runs
                print(f"{name}/{path} failed: {type(e).__name__}: {e}")
                status = 1
        print(f"\n{name}: {folder.name}, frames 0-{n - 1}, max depth {ds.max_depth:g} m, two-view pairing "
              f"'{ds.pairing}', landmark pose prior '{ds.pose_prior}'")
        print(format_rows(ds, n, rows), flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
