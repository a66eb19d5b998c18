"""Run the pipeline over a sequence, write outputs, evaluate against ground truth.

Outputs in ``out_dir``:

* ``depth/<stem>.png`` -- uint16 metric depth, metres x 256, 0 = invalid (KITTI convention)
* ``uncertainty/<stem>.png`` -- with ``uncertainty=True``: 1-sigma of that depth, same encoding
* ``frames.jsonl`` -- one JSON object per processed frame
* ``metrics.json`` -- when the sequence has ground-truth depth

Every file is written under a temporary name and renamed into place when complete, so
an interrupted run never leaves a half-written file; ``frames.jsonl`` and
``metrics.json`` appear only when the whole run succeeded.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .io.base import Sequence
from .io.depth_png import write_bytes_atomic, write_depth_png
from .pipeline import Pipeline
from .types import FrameResult


@dataclass
class RunSummary:
    """What a run did. ``metrics`` maps row name to averaged metrics dicts: the point source
    ("sfm", or a reference source such as "lidar:16") and "oracle"."""

    frames_in_sequence: int
    frames_processed: int
    frames_with_depth: int
    status_counts: dict[str, int]
    metrics: dict[str, dict] = field(default_factory=dict)
    point_accuracy: dict | None = None
    seconds: float = 0.0
    disparity_kind: str = ""

    def to_json(self) -> dict:
        return asdict(self)


def run_sequence(
    sequence: Sequence,
    pipeline: Pipeline,
    out_dir,
    *,
    max_frames: int | None = None,
    uncertainty: bool = False,
    min_eval_depth: float = 1e-3,
    max_eval_depth: float = 80.0,
    progress: bool | None = None,
) -> RunSummary:
    """Process ``sequence`` (or its first ``max_frames`` frames) and write outputs to ``out_dir``.

    Args:
        progress: show a progress bar (None = only when stderr is a terminal).

    Raises:
        InputError: unreadable inputs; partially written outputs are removed.
    """
    from tqdm import tqdm

    from .metrics import average_metrics, compute_metrics, oracle_fit
    from .rescale import depth_sigma_map, metric_depth

    out_dir = Path(out_dir)
    depth_dir, sigma_dir = out_dir / "depth", out_dir / "uncertainty"
    for folder in (depth_dir, sigma_dir) if uncertainty else (depth_dir,):
        folder.mkdir(parents=True, exist_ok=True)
    n_total = len(sequence)
    n = n_total if max_frames is None else min(n_total, max_frames)
    t_start = time.perf_counter()

    source = pipeline.settings.points
    # triangulated points are checked against ground truth; reference points come from it
    point_accuracy_fn = _point_accuracy_fn() if sequence.has_gt_depth and source == "sfm" else None
    sfm_metrics, oracle_metrics, point_rows = [], [], []
    status_counts: dict[str, int] = {}
    frames_with_depth = 0
    lines_path = out_dir / ".frames.jsonl.partial"
    try:
        with open(lines_path, "w") as lines:
            bar = tqdm(range(n), desc=f"vio-depth {sequence.name}", unit="frame",
                       disable=(not sys.stderr.isatty()) if progress is None else not progress,
                       file=sys.stderr)
            for i in bar:
                frame = sequence[i]
                res: FrameResult = pipeline.process(frame)
                status_counts[res.status.value] = status_counts.get(res.status.value, 0) + 1
                if res.depth is not None:
                    frames_with_depth += 1
                    write_depth_png(depth_dir / f"{frame.stem}.png", res.depth)
                    if uncertainty:
                        write_depth_png(sigma_dir / f"{frame.stem}.png", depth_sigma_map(res.disparity, res.fit))
                gt = frame.gt_depth() if sequence.has_gt_depth else None
                if gt is not None and res.depth is not None:
                    m = compute_metrics(res.depth, gt, min_depth=min_eval_depth, max_depth=max_eval_depth)
                    sfm_metrics.append(m)
                    res.extra["abs_rel"] = round(float(m.abs_rel), 5)
                    res.extra["delta1"] = round(float(m.delta1), 5)
                    ofit = oracle_fit(res.disparity, gt, min_depth=min_eval_depth, max_depth=max_eval_depth)
                    if ofit.ok:
                        om = compute_metrics(metric_depth(res.disparity, ofit), gt, min_depth=min_eval_depth,
                                             max_depth=max_eval_depth)
                        oracle_metrics.append(om)
                        res.extra["oracle_abs_rel"] = round(float(om.abs_rel), 5)
                if gt is not None and point_accuracy_fn is not None and res.points_uv is not None and len(res.points_uv):
                    acc = point_accuracy_fn(res.points_uv, res.points_depth, gt)
                    point_rows.append(acc)
                    res.extra.update(_point_json(acc))
                lines.write(json.dumps(res.to_json()) + "\n")
                bar.set_postfix(depth=f"{frames_with_depth}/{i + 1}")
        summary = RunSummary(
            frames_in_sequence=n_total,
            frames_processed=n,
            frames_with_depth=frames_with_depth,
            status_counts=status_counts,
            seconds=round(time.perf_counter() - t_start, 2),
            disparity_kind=getattr(pipeline.disparity_source, "kind", ""),
        )
        if sfm_metrics:
            summary.metrics[source] = average_metrics(sfm_metrics).to_json()
            if oracle_metrics:
                summary.metrics["oracle"] = average_metrics(oracle_metrics).to_json()
        if point_rows:
            summary.point_accuracy = _aggregate_points(point_rows)
        if sequence.has_gt_depth:
            write_bytes_atomic(out_dir / "metrics.json", (json.dumps(summary.to_json(), indent=2) + "\n").encode())
        os.replace(lines_path, out_dir / "frames.jsonl")
    except BaseException:
        lines_path.unlink(missing_ok=True)
        raise
    return summary


def _point_accuracy_fn():
    try:
        from .point_accuracy import point_depth_errors
    except ImportError:  # pragma: no cover - issue 4 module absent
        return None
    return point_depth_errors


def _point_json(acc) -> dict:
    return {
        "points_evaluated": int(acc.count),
        "points_rel_err_median": None if acc.count == 0 else round(float(acc.median), 5),
        "points_rel_err_p90": None if acc.count == 0 else round(float(acc.p90), 5),
    }


def _aggregate_points(rows) -> dict:
    rows = [r for r in rows if r.count > 0]
    if not rows:
        return {"frames": 0}
    return {
        "frames": len(rows),
        "points_per_frame_median": float(np.median([r.count for r in rows])),
        "rel_err_median_of_frames": float(np.median([r.median for r in rows])),
        "rel_err_p90_median_of_frames": float(np.median([r.p90 for r in rows])),
    }


def format_table(summary: RunSummary) -> str:
    """The printed results table: a row for the point source (``sfm``, ``lidar:16``...) and ``oracle``."""
    lines = []
    if summary.metrics:
        head = f"{'':10s} {'delta1':>8s} {'AbsRel':>8s} {'RMSE':>8s} {'frames evaluated':>17s} {'frames in sequence':>19s}"
        lines.append(head)
        for name, m in summary.metrics.items():
            lines.append(
                f"{name:10s} {m['delta1']:8.4f} {m['abs_rel']:8.4f} {m['rmse']:8.3f} "
                f"{m['n_frames']:17d} {summary.frames_in_sequence:19d}"
            )
    lines.append(
        f"metric depth for {summary.frames_with_depth} of {summary.frames_processed} processed frames "
        f"({summary.frames_in_sequence} in sequence); statuses: "
        + ", ".join(f"{k} {v}" for k, v in sorted(summary.status_counts.items()))
    )
    if summary.point_accuracy and summary.point_accuracy.get("frames"):
        p = summary.point_accuracy
        lines.append(
            f"triangulated points vs ground truth: median |z-z_gt|/z_gt {p['rel_err_median_of_frames']:.3f}, "
            f"p90 {p['rel_err_p90_median_of_frames']:.3f} (medians over {p['frames']} frames, "
            f"{p['points_per_frame_median']:.0f} points/frame)"
        )
    if summary.disparity_kind == "simulated":
        lines.append("note: the disparity of this sequence is SIMULATED (not a Depth Anything prediction)")
    return "\n".join(lines)
