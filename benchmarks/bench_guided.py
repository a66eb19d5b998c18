"""Benchmark: pose-guided matching against today's exhaustive matching, in the same run (issue 24 item 3).

For each dataset a fresh :class:`vio_depth.pipeline.Pipeline` (SIFT, the chosen pose source,
default triangulation and rescaler settings, RANSAC seed 0) processes the same frames twice:
``exhaustive`` (``SiftSettings()``, the default) and ``guided`` (``SiftSettings(guided=
GuidedSettings(enabled=True))``: nearest neighbours only inside each keypoint's epipolar band,
:mod:`matchers.guided`). Everything else is identical.

Datasets: those of ``benchmarks/bench_matchers.py`` (``street``, ``room``: the bundled SIMULATED
samples with their own SIMULATED disparity and exact poses; ``kitti``: KITTI-tiny, real images
and OXTS poses (stated uncertainty ``ins``), disparity SIMULATED from the LiDAR
(``--disparity simulated``); ``7scenes`` when asked). The dense AbsRel is therefore SIMULATED
on every dataset: it measures how well the points recover each frame's scale and shift.

Per frame (``--per-frame``) and summed per variant:

* ``matches``: matches of the frame's pairs (summed over its up to 2 keyframe pairs);
* ``inlier``: the fraction of those matches that passed every triangulation check (epipolar,
  parallax, cheirality, reprojection, depth range);
* ``points``: merged valid points of the frame (what the fit gets);
* ``pt err``: median ``|z - z_gt| / z_gt`` of the points with a ground truth;
* ``AbsRel``: dense rescaled depth against the ground truth (frames with metric depth);
* ``written``: frames that got metric depth (the frames ``vio-depth run`` writes);
* ``match ms``: seconds of the points stage's matching step (all pairs of the frame), from the
  stage's own timer: median and p90 over the paired frames, and the total.

Run: ``python benchmarks/bench_guided.py [--datasets street,room,kitti] [--poses gt]
[--frames N] [--per-frame]``. The verdict line says whether guided matching was at least as
accurate (AbsRel within 1 %, no fewer frames written) and faster (total matching time) on
every dataset; it is printed, not enforced.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]  # this checkout's code first

from bench_matchers import DATASETS, machine_line  # noqa: E402

VARIANTS = ("exhaustive", "guided")


@dataclass
class FrameRow:
    index: int
    matches: int = 0
    valid: int = 0
    points: int = 0
    pt_err: float = float("nan")
    abs_rel: float = float("nan")
    written: bool = False
    match_s: float | None = None  # None: the frame was not matched (no pair)


@dataclass
class VariantRun:
    variant: str
    frames: list[FrameRow] = field(default_factory=list)
    errors: list[np.ndarray] = field(default_factory=list)
    seconds: float = 0.0

    def summary(self) -> dict:
        paired = [f for f in self.frames if f.match_s is not None]
        match_ms = np.array([1e3 * f.match_s for f in paired]) if paired else np.zeros(0)
        matches = sum(f.matches for f in self.frames)
        abs_rel = [f.abs_rel for f in self.frames if np.isfinite(f.abs_rel)]
        errs = np.concatenate(self.errors) if self.errors else np.zeros(0)
        return {
            "frames": len(self.frames), "written": sum(f.written for f in self.frames),
            "matches": matches, "inlier": sum(f.valid for f in self.frames) / matches if matches else float("nan"),
            "points": float(np.mean([f.points for f in paired])) if paired else float("nan"),
            "pt_err": float(np.median(np.abs(errs))) if len(errs) else float("nan"),
            "abs_rel": float(np.mean(abs_rel)) if abs_rel else float("nan"),
            "match_ms_p50": float(np.median(match_ms)) if len(match_ms) else float("nan"),
            "match_ms_p90": float(np.percentile(match_ms, 90)) if len(match_ms) else float("nan"),
            "match_s_total": float(match_ms.sum() / 1e3), "seconds": self.seconds,
        }


def run_variant(ds, sequence, indices, variant: str, poses: str) -> VariantRun:
    from matchers import GuidedSettings, SiftSettings
    from vio_depth.disparity import DisparitySettings
    from vio_depth.evaluation.metrics import compute_metrics
    from vio_depth.evaluation.point_accuracy import point_depth_errors
    from vio_depth.pipeline import Pipeline, PipelineSettings

    settings = PipelineSettings.from_presets(pairing=ds.pairing, poses=poses)
    matcher = SiftSettings(guided=GuidedSettings(enabled=variant == "guided"))
    disparity = DisparitySettings(source="simulated" if ds.disparity == "gt_simulated" else "sequence")
    settings = replace(settings, matcher=matcher, disparity=disparity)
    pipeline = Pipeline(settings, sequence=sequence)
    run = VariantRun(variant)
    t0 = time.perf_counter()
    for i in indices:
        frame = sequence[i]
        res = pipeline.process(frame)
        row = FrameRow(i, written=res.depth is not None)
        pts = res.points
        if pts is not None and pts.partners:
            row.matches = int(pts.matches)
            row.valid = int(pts.point_status.get("valid", 0))
            row.points = 0 if pts.depth is None else int(len(pts.depth))
            row.match_s = float(pts.timings.get("matching", 0.0))
        gt = frame.gt_depth()
        if gt is not None:
            if res.points_uv is not None and len(res.points_uv):
                acc = point_depth_errors(res.points_uv, res.points_depth, gt)
                if acc.count:
                    ok = acc.evaluated
                    e = (res.points_depth[ok] - acc.gt_depth[ok]) / acc.gt_depth[ok]
                    run.errors.append(e)
                    row.pt_err = float(np.median(np.abs(e)))
            if res.depth is not None:
                m = compute_metrics(res.depth, gt, max_depth=ds.max_depth)
                if m.n_pixels:
                    row.abs_rel = float(m.abs_rel)
        run.frames.append(row)
    run.seconds = time.perf_counter() - t0
    return run


def _f(x, spec):
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def summary_table(name: str, runs: list[VariantRun]) -> list[str]:
    head = ("| data | matching | frames | written | matches | inlier | points/frame | pt err | AbsRel | "
            "match ms p50 | p90 | match s total |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in runs:
        s = r.summary()
        lines.append(f"| {name} | {r.variant} | {s['frames']} | {s['written']} | {s['matches']} | "
                     f"{_f(s['inlier'], '.3f')} | {_f(s['points'], '.0f')} | {_f(s['pt_err'], '.4f')} | "
                     f"{_f(s['abs_rel'], '.4f')} | {_f(s['match_ms_p50'], '.0f')} | {_f(s['match_ms_p90'], '.0f')} | "
                     f"{_f(s['match_s_total'], '.2f')} |")
    return lines


def per_frame_table(runs: list[VariantRun]) -> list[str]:
    head = "| frame | " + " | ".join(f"{r.variant} matches / inlier / points / AbsRel / ms" for r in runs) + " |"
    lines = [head, "|" + "---|" * (len(runs) + 1)]
    for rows in zip(*(r.frames for r in runs)):
        cells = []
        for f in rows:
            inl = f.valid / f.matches if f.matches else float("nan")
            ms = "-" if f.match_s is None else f"{1e3 * f.match_s:.0f}"
            cells.append(f"{f.matches} / {_f(inl, '.2f')} / {f.points} / {_f(f.abs_rel, '.4f')}"
                         f"{'' if f.written else ' (not written)'} / {ms}")
        lines.append(f"| {rows[0].index} | " + " | ".join(cells) + " |")
    return lines


def verdict(results: dict[str, list[VariantRun]]) -> str:
    notes, accurate, faster = [], True, True
    for name, (ex, gd) in results.items():
        a, b = ex.summary(), gd.summary()
        acc = (b["written"] >= a["written"] and (not np.isfinite(a["abs_rel"])
                                                 or b["abs_rel"] <= 1.01 * a["abs_rel"]))
        fast = b["match_s_total"] < a["match_s_total"]
        accurate &= acc
        faster &= fast
        notes.append(f"{name}: AbsRel {_f(a['abs_rel'], '.4f')} -> {_f(b['abs_rel'], '.4f')}, written "
                     f"{a['written']} -> {b['written']}, matching {a['match_s_total']:.2f} -> "
                     f"{b['match_s_total']:.2f} s")
    what = ("as accurate and faster" if accurate and faster else "as accurate but NOT faster" if accurate
            else "faster but NOT as accurate" if faster else "neither as accurate nor faster")
    return f"verdict: compared with exhaustive matching, guided matching is {what} on these data ({'; '.join(notes)})"


def main(argv=None) -> int:
    from vio_core.errors import UnknownNameError
    from vio_depth.io import open_sequence

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--datasets", default="street,room,kitti", help=f"comma-separated, from {', '.join(DATASETS)}")
    p.add_argument("--poses", default="gt", help="pose source preset (gt, imu, ...)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="at most N frames per dataset")
    p.add_argument("--per-frame", action="store_true", help="also print one row per frame")
    args = p.parse_args(argv)
    names = [n for n in args.datasets.split(",") if n]
    for n in names:
        if n not in DATASETS:
            raise UnknownNameError("benchmark dataset", n, DATASETS)

    t0 = time.perf_counter()
    print(f"# bench_guided, {datetime.date.today().isoformat()}; command: python benchmarks/bench_guided.py "
          f"{' '.join(argv if argv is not None else sys.argv[1:])}")
    results, tables = {}, []
    for name in names:
        ds = DATASETS[name]
        if not ds.path.is_dir():
            print(f"\n## {name}: skipped ({ds.path} not found)")
            continue
        sequence = open_sequence(ds.path)
        indices = ds.frame_indices(len(sequence), args.frames)
        print(f"\n## {name}: {ds.label}\n{len(indices)} frames (indices {indices[0]}-{indices[-1]}"
              f"{f', every {ds.step}th' if ds.step > 1 else ''}); poses {args.poses}; pairing '{ds.pairing}'",
              flush=True)
        runs = [run_variant(ds, sequence, indices, v, args.poses) for v in VARIANTS]
        results[name] = runs
        if args.per_frame:
            print("\n".join(per_frame_table(runs)))
        tables.extend(summary_table(name, runs)[0 if not tables else 2:])
    print("\n## summary\n")
    print("\n".join(tables))
    print()
    print(verdict(results))
    print(f"\n# machine: {machine_line('cpu')}; total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    from vio_core.errors import VioDepthError

    try:
        sys.exit(main())
    except VioDepthError as exc:
        print(f"bench_guided: error: {exc}", file=sys.stderr)
        sys.exit(1)
