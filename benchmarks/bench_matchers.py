"""Benchmark: every matcher preset on real and simulated sequences, through the real pipeline.

For each dataset x matcher a fresh :class:`vio_depth.pipeline.Pipeline` (ground-truth pose
source, default triangulation and rescaler settings, the CLI's defaults: fallbacks and
temporal filter on, RANSAC seed 0) processes the same frames in order. The pipeline's matcher is
wrapped in a timing proxy, so the stages run exactly as in ``vio-depth run`` while
extraction and matching are timed separately (``time.perf_counter`` around each call; the
image is loaded before the extraction call and is not timed).

Datasets (folders located relative to the repository root; a missing one is skipped):

========  ===========================================  =========  =====================  =========
name      folder                                       pairing    disparity              max depth
========  ===========================================  =========  =====================  =========
kitti     ../shared/data/kitti_tiny (KITTI raw, 7 fr.)  kitti      SIMULATED from LiDAR   80 m
7scenes   ../shared/data/7scenes_redkitchen             indoor     SIMULATED from Kinect  10 m
street    sample_sequences/street (SIMULATED scene)     kitti      the sample's own       80 m
                                                                   (SIMULATED)
room      sample_sequences/room (SIMULATED scene)       indoor     the sample's own       10 m
                                                                   (SIMULATED)
========  ===========================================  =========  =====================  =========

KITTI-tiny and 7-Scenes carry no disparity maps: their disparity is SIMULATED from the
densified ground truth by :class:`vio_depth.disparity.SimulatedDisparitySource` (``--disparity simulated``)
(seed 0, default settings). The dense delta1 / AbsRel columns are therefore SIMULATED on
every dataset: they measure how well each matcher's points recover the per-frame scale
and shift, not Depth Anything's accuracy.

Columns (one row per matcher). The pipeline matches a frame with up to
``pairing.pairs_per_frame`` (2) keyframes and merges their valid points, keeping one point
per current keypoint (its most certain depth); "pair" is one (frame, keyframe) matching:

* ``extract s/frame``: median seconds of one ``matcher.extract`` call;
* ``match s/pair``: median seconds of one ``matcher.match`` call;
* ``pairs``: matchings run; ``matches``: mean matches per pair;
* ``epi ok``: mean matches per pair that passed the known-pose epipolar check
  (triangulation status != EPIPOLAR; the matches of a pair with fewer than
  ``min_matches`` (20) are not triangulated and count as not passing);
* ``valid``: mean triangulated points per pair that passed every check (epipolar,
  parallax, cheirality, reprojection, depth range);
* ``points/frame``: mean valid points per paired frame after merging its pairs (distinct
  keypoints: what the robust fit gets); ``total`` their sum over the frames;
* ``vs sift``: ``total`` divided by SIFT's on the same dataset in the same run;
* ``pt err``: median over all evaluated points of ``|z - z_gt| / z_gt``
  (:func:`vio_depth.evaluation.point_depth_errors`, reference = median of the valid
  ground truth in a 5 x 5 window, same on every dataset); ``bias`` the median of the signed
  ``(z - z_gt) / z_gt``; ``n eval`` how many points had a reference (the merged points the
  pipeline sampled a disparity for; points without ground truth in their window are not
  counted); a second table splits ``pt err`` by ground-truth depth (bins at 1/8, 1/4 and
  1/2 of the dataset's max depth);
* ``delta1``, ``AbsRel``: dense rescaled depth against the ground truth, frame-averaged
  (:func:`vio_depth.evaluation.compute_metrics`, depths in [1e-3, max depth]) over the
  ``frames eval`` frames that got metric depth. The ``oracle`` line under each table is the
  least-squares fit of the same SIMULATED disparity to the ground truth on every processed
  frame: the floor any rescaling of that disparity can reach.

Frames (defaults keep the whole run well under 15 minutes on a 2-core CPU, where DISK +
LightGlue costs seconds per frame): ``kitti`` all 7; ``7scenes`` frames 0-120, every 6th
(21 frames); ``street`` the first 16; ``room`` frames 0-60, every 4th (16 frames). ``--frames N`` caps
every dataset at N frames (after the stride).

Threads: torch's default (printed); matchers run on ``--device`` (default cpu).

Run: ``python benchmarks/bench_matchers.py [--datasets kitti,7scenes,street,room]
[--matchers sift,disk+lightglue,...] [--frames N]``. Exit status 0 unless a dataset or
matcher fails to run; the KITTI done-when verdict is printed, not enforced.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO / ".." / "shared" / "data"
BASELINE = "sift"
#: where a dataset's disparity comes from (see :class:`BenchDataset`)
DISPARITY_KINDS = ("sequence", "gt_simulated")


@dataclass(frozen=True)
class BenchDataset:
    """One benchmark dataset.

    Attributes:
        name: short name used on the command line.
        path: sequence folder.
        pairing: pairing preset name (``vio_depth.keyframes.PAIRING_PRESETS``).
        disparity: "sequence" (the sequence's own, SIMULATED for the samples) or
            "gt_simulated" (SIMULATED from the densified ground truth, ``--disparity simulated``).
        max_depth: metres, upper bound of the dense evaluation.
        start, stop, step: frame indices ``range(start, stop, step)`` (stop None = all).
        label: what the data are, printed with the table.
    """

    name: str
    path: Path
    pairing: str
    disparity: str
    max_depth: float
    start: int = 0
    stop: int | None = None
    step: int = 1
    label: str = ""

    def __post_init__(self):
        from vio_core.errors import UnknownNameError

        if self.disparity not in DISPARITY_KINDS:
            raise UnknownNameError("benchmark disparity kind", self.disparity, DISPARITY_KINDS)

    def frame_indices(self, n_frames: int, cap: int | None) -> list[int]:
        stop = n_frames if self.stop is None else min(self.stop, n_frames)
        idx = list(range(self.start, stop, self.step))
        return idx if cap is None else idx[:cap]


DATASETS: dict[str, BenchDataset] = {
    d.name: d for d in (
        BenchDataset("kitti", SHARED_DATA / "kitti_tiny", "kitti", "gt_simulated", 80.0,
                     label="KITTI raw 2011_09_26_drive_0023 (real images, OXTS poses, LiDAR depth); "
                           "disparity SIMULATED from densified LiDAR"),
        BenchDataset("7scenes", SHARED_DATA / "7scenes_redkitchen", "indoor", "gt_simulated", 10.0,
                     start=0, stop=121, step=6,
                     label="7-Scenes redkitchen (real images, KinectFusion poses, Kinect depth); "
                           "disparity SIMULATED from densified depth"),
        BenchDataset("street", REPO / "sample_sequences" / "street", "kitti", "sequence", 80.0, stop=16,
                     label="bundled sample street (SIMULATED rendering, exact depth); its own SIMULATED disparity"),
        BenchDataset("room", REPO / "sample_sequences" / "room", "indoor", "sequence", 10.0, stop=61, step=4,
                     label="bundled sample room (SIMULATED rendering, exact depth); its own SIMULATED disparity"),
    )
}


class TimedMatcher:
    """Wraps a matcher; records the seconds of every ``extract`` and ``match`` call."""

    def __init__(self, matcher):
        self.inner = matcher
        self.name = matcher.name
        self.extract_s: list[float] = []
        self.match_s: list[float] = []

    def extract(self, image):
        t0 = time.perf_counter()
        out = self.inner.extract(image)
        self.extract_s.append(time.perf_counter() - t0)
        return out

    def match(self, feats_a, feats_b):
        t0 = time.perf_counter()
        out = self.inner.match(feats_a, feats_b)
        self.match_s.append(time.perf_counter() - t0)
        return out


@dataclass
class MatcherRow:
    """Aggregated figures of one matcher on one dataset (see the module docstring)."""

    matcher: str
    frames: int = 0
    extract_s: float = float("nan")
    match_s: float = float("nan")
    n_extract: int = 0
    pairs: int = 0  # matchings run
    matches: int = 0  # summed over pairs
    epipolar_ok: int = 0  # summed over pairs
    valid: int = 0  # summed over pairs (a keypoint valid in two pairs counts twice)
    points: list[int] = field(default_factory=list)  # merged valid points per paired frame
    dense: list = field(default_factory=list)  # DepthMetrics per evaluated frame
    statuses: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    signed_errors: list[np.ndarray] = field(default_factory=list)  # (z - z_gt) / z_gt per frame
    gt_depths: list[np.ndarray] = field(default_factory=list)  # z_gt (m) of the same points

    @property
    def total_points(self) -> int:
        return int(sum(self.points))

    @property
    def n_point_eval(self) -> int:
        return int(sum(len(e) for e in self.signed_errors))

    def _pooled(self) -> np.ndarray:
        return np.concatenate(self.signed_errors) if self.signed_errors else np.zeros(0)

    @property
    def point_error_median(self) -> float:
        e = self._pooled()
        return float(np.median(np.abs(e))) if len(e) else float("nan")

    @property
    def point_error_bias(self) -> float:
        e = self._pooled()
        return float(np.median(e)) if len(e) else float("nan")

    def error_by_depth(self, edges) -> list[tuple[int, float]]:
        """(count, median |z - z_gt| / z_gt) of the points with z_gt in each ``[edges[k], edges[k+1])`` metres."""
        if not self.signed_errors:
            return [(0, float("nan"))] * (len(edges) - 1)
        e, z = np.abs(np.concatenate(self.signed_errors)), np.concatenate(self.gt_depths)
        out = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            k = (z >= lo) & (z < hi)
            out.append((int(k.sum()), float(np.median(e[k])) if k.any() else float("nan")))
        return out

    def per_pair(self, total: int) -> float:
        return total / self.pairs if self.pairs else float("nan")


def _disparity_settings(ds: BenchDataset):
    from vio_depth.disparity import DisparitySettings

    return DisparitySettings(source="simulated" if ds.disparity == "gt_simulated" else "sequence")


def run_one(ds: BenchDataset, sequence, indices: list[int], matcher: str, device: str,
            oracle: dict[int, object] | None) -> MatcherRow:
    """Run the pipeline with ``matcher`` over ``indices`` of ``sequence`` and aggregate.

    ``oracle``: when given, filled with the oracle-fit metrics of each processed frame.
    """
    from dataclasses import replace

    from matchers import create_matcher
    from vio_depth.evaluation.metrics import compute_metrics, oracle_fit
    from vio_depth.evaluation.point_accuracy import point_depth_errors
    from vio_depth.pipeline import Pipeline, PipelineSettings
    from vio_depth.rescale import metric_depth

    settings = PipelineSettings.from_presets(matcher=matcher, pairing=ds.pairing)
    settings = replace(settings, disparity=_disparity_settings(ds))
    timed = TimedMatcher(create_matcher(settings.matcher, device=device))
    pipeline = Pipeline(settings, sequence=sequence, matcher=timed)
    row = MatcherRow(matcher)
    t_start = time.perf_counter()
    for i in indices:
        frame = sequence[i]
        res = pipeline.process(frame)
        row.frames += 1
        row.statuses[res.status.value] = row.statuses.get(res.status.value, 0) + 1
        gt = frame.gt_depth()
        if res.points.partners:
            counts = res.points.point_status
            row.matches += int(res.points.matches)
            row.epipolar_ok += int(sum(counts.values())) - int(counts.get("epipolar", 0))
            row.valid += int(counts.get("valid", 0))
            row.points.append(int(len(res.points.depth)))
        if gt is None:
            continue
        if res.points_uv is not None and len(res.points_uv):
            acc = point_depth_errors(res.points_uv, res.points_depth, gt)
            if acc.count:
                ok = acc.evaluated
                row.signed_errors.append((res.points_depth[ok] - acc.gt_depth[ok]) / acc.gt_depth[ok])
                row.gt_depths.append(acc.gt_depth[ok])
        if res.depth is not None:
            m = compute_metrics(res.depth, gt, max_depth=ds.max_depth)
            if m.n_pixels:
                row.dense.append(m)
        if oracle is not None and res.disparity is not None:
            fit = oracle_fit(res.disparity, gt, max_depth=ds.max_depth)
            if fit.ok:
                om = compute_metrics(metric_depth(res.disparity, fit), gt, max_depth=ds.max_depth)
                if om.n_pixels:
                    oracle[i] = om
    row.seconds = time.perf_counter() - t_start
    row.n_extract, row.pairs = len(timed.extract_s), len(timed.match_s)
    if timed.extract_s:
        row.extract_s = float(np.median(timed.extract_s))
    if timed.match_s:
        row.match_s = float(np.median(timed.match_s))
    return row


def _fmt(x: float, spec: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def format_table(ds: BenchDataset, rows: list[MatcherRow], oracle: dict) -> str:
    """Markdown table of one dataset (see the module docstring for the columns)."""
    from vio_depth.evaluation.metrics import average_metrics

    base = next((r for r in rows if r.matcher == BASELINE), None)
    head = ("| matcher | extract s/frame | match s/pair | pairs | matches | epi ok | valid | points/frame | total | "
            f"vs {BASELINE} | pt err | bias | n eval | delta1 | AbsRel | frames eval |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        ratio = r.total_points / base.total_points if base is not None and base.total_points else float("nan")
        dense = average_metrics(r.dense) if r.dense else None
        lines.append(
            f"| {r.matcher} | {_fmt(r.extract_s, '.3f')} | {_fmt(r.match_s, '.3f')} | {r.pairs} | "
            f"{_fmt(r.per_pair(r.matches), '.0f')} | {_fmt(r.per_pair(r.epipolar_ok), '.0f')} | "
            f"{_fmt(r.per_pair(r.valid), '.0f')} | {_fmt(np.mean(r.points) if r.points else None, '.0f')} | "
            f"{r.total_points} | {_fmt(ratio, '.2f')}x | {_fmt(r.point_error_median, '.4f')} | "
            f"{_fmt(r.point_error_bias, '+.4f')} | {r.n_point_eval} | "
            f"{_fmt(dense.delta1 if dense else None, '.4f')} | {_fmt(dense.abs_rel if dense else None, '.4f')} | "
            f"{len(r.dense)} |"
        )
    if oracle:
        om = average_metrics(list(oracle.values()))
        lines.append(f"\noracle (least-squares fit of the same SIMULATED disparity to the ground truth, "
                     f"{om.n_frames} frames): delta1 {om.delta1:.4f}, AbsRel {om.abs_rel:.4f}")
    edges = [0.0, ds.max_depth / 8, ds.max_depth / 4, ds.max_depth / 2, np.inf]
    names = [f"{lo:g}-{hi:g} m" if np.isfinite(hi) else f">= {lo:g} m" for lo, hi in zip(edges[:-1], edges[1:])]
    lines.append("\npt err by ground-truth depth (points, median |z - z_gt| / z_gt):\n")
    lines.append("| matcher | " + " | ".join(names) + " |")
    lines.append("|" + "---|" * (len(names) + 1))
    for r in rows:
        cells = [f"{n} pts, {_fmt(e, '.4f')}" for n, e in r.error_by_depth(edges)]
        lines.append(f"| {r.matcher} | " + " | ".join(cells) + " |")
    lines.append("")
    for r in rows:
        lines.append(f"{r.matcher}: {r.frames} frames in {r.seconds:.1f} s, {r.n_extract} extractions, "
                     f"{r.pairs} matchings; statuses " + ", ".join(f"{k} {v}" for k, v in sorted(r.statuses.items())))
    return "\n".join(lines)


def kitti_verdict(rows: list[MatcherRow]) -> str:
    """Done-when on KITTI-tiny: a learned matcher with more valid points than SIFT at no worse median error."""
    base = next((r for r in rows if r.matcher == BASELINE), None)
    if base is None:
        return f"verdict: not evaluated ({BASELINE} was not run)"
    winners = [r.matcher for r in rows if r.matcher != BASELINE and r.total_points > base.total_points
               and np.isfinite(r.point_error_median) and r.point_error_median <= base.point_error_median]
    figs = "; ".join(f"{r.matcher} {r.total_points} points, median error {_fmt(r.point_error_median, '.4f')}"
                     for r in rows)
    if winners:
        return f"verdict: HOLDS for {', '.join(winners)} ({figs})"
    return f"verdict: does NOT hold: no learned matcher has more valid points than {BASELINE} at no worse median error ({figs})"


def machine_line(device: str) -> str:
    parts = [f"{platform.machine()}", f"{os.cpu_count()} CPU cores", f"python {platform.python_version()}",
             f"numpy {np.__version__}"]
    try:
        import cv2

        parts.append(f"opencv {cv2.__version__}")
    except ImportError:  # pragma: no cover
        pass
    if "torch" in sys.modules:
        import torch

        parts.append(f"torch {torch.__version__} ({torch.get_num_threads()} threads, default)")
        parts.append(f"cuda available: {torch.cuda.is_available()}")
    parts.append(f"matchers on {device}")
    return ", ".join(parts)


def main(argv=None) -> int:
    from matchers import available_matchers
    from vio_core.errors import UnknownNameError
    from vio_depth.io import open_sequence

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--datasets", default=",".join(DATASETS), help=f"comma-separated, from {', '.join(DATASETS)}")
    p.add_argument("--matchers", default=None, help="comma-separated presets (default: all, sift first)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="at most N frames per dataset")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="device of the learned matchers")
    args = p.parse_args(argv)

    names = [n for n in args.datasets.split(",") if n]
    for n in names:
        if n not in DATASETS:
            raise UnknownNameError("benchmark dataset", n, DATASETS)
    matchers = args.matchers.split(",") if args.matchers else available_matchers()
    for m in matchers:
        if m not in available_matchers():
            raise UnknownNameError("matcher", m, available_matchers())
    matchers = sorted(matchers, key=lambda m: (m != BASELINE, m))  # baseline first
    if args.frames is not None and args.frames < 2:
        p.error("--frames must be >= 2")

    t0 = time.perf_counter()
    print(f"# bench_matchers, {datetime.date.today().isoformat()}; "
          f"command: python benchmarks/bench_matchers.py {' '.join(argv if argv is not None else sys.argv[1:])}")
    for name in names:
        ds = DATASETS[name]
        if not ds.path.is_dir():
            print(f"\n## {name}: skipped ({ds.path} not found)")
            continue
        sequence = open_sequence(ds.path)
        indices = ds.frame_indices(len(sequence), args.frames)
        step = f", every {ds.step}th" if ds.step > 1 else ""
        print(f"\n## {name}: {ds.label}\n{len(indices)} frames (indices {indices[0]}-{indices[-1]}{step}) of "
              f"{len(sequence)}; pairing preset '{ds.pairing}'; dense evaluation up to {ds.max_depth:g} m",
              flush=True)
        rows, oracle = [], {}
        for m in matchers:
            row = run_one(ds, sequence, indices, m, args.device, oracle if m == matchers[0] else None)
            rows.append(row)
            print(f"  {m}: done in {row.seconds:.1f} s", file=sys.stderr, flush=True)
        print(format_table(ds, rows, oracle))
        if name == "kitti":
            print(kitti_verdict(rows))
    print(f"\n# machine: {machine_line(args.device)}; total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    from vio_core.errors import VioDepthError

    try:
        sys.exit(main())
    except VioDepthError as exc:
        print(f"bench_matchers: error: {exc}", file=sys.stderr)
        sys.exit(1)
