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
    outputs: dict = field(default_factory=dict)  # issue 13: what the optional exports wrote

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class _FrameRecord:
    """Everything kept of one processed frame until the outputs are written."""

    json: dict
    status: str
    has_depth: bool
    metrics: object = None  # DepthMetrics of the prediction
    oracle: object = None  # DepthMetrics of the oracle fit
    points: object = None  # PointAccuracy of the triangulated points


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
    backfill: bool = True,
    export=None,
) -> RunSummary:
    """Process ``sequence`` (or its first ``max_frames`` frames) and write outputs to ``out_dir``.

    Args:
        progress: show a progress bar (None = only when stderr is a terminal).
        backfill: offline second chance for the frames at the start of the sequence that got
            no depth because no earlier keyframe was far enough away: after the forward pass,
            a fresh pipeline runs backwards in time from a later frame, so those frames pair
            with *later* keyframes (:func:`_backfill`). Only results with depth replace the
            forward ones; they are marked ``"backfilled": true`` in ``frames.jsonl``.
            Needs a pose source that works in both directions (``gt``; ``imu`` integrates
            forward only, so its backward pairs fail and nothing changes).
        export: :class:`vio_depth.export.ExportSettings` of the optional outputs (float
            ``.npy``, previews, PLY clouds, report thumbnails), or None.

    Raises:
        InputError: unreadable inputs; partially written outputs are removed.
    """
    from tqdm import tqdm

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
    # --- issue 13: optional exports (the lead ports this into run/outputs.py) ---
    exporter = None
    if export is not None and export.any:
        from .export import RunExporter

        exporter = RunExporter(out_dir, export)

    def record(frame, res: FrameResult) -> _FrameRecord:
        rec = _record(frame, res, sequence.has_gt_depth, depth_dir, sigma_dir if uncertainty else None,
                      min_eval_depth, max_eval_depth, point_accuracy_fn)
        if exporter is not None:  # issue 13
            exporter.add_frame(frame, res)
        return rec

    records: dict[int, _FrameRecord] = {}
    bar = tqdm(range(n), desc=f"vio-depth {sequence.name}", unit="frame",
               disable=(not sys.stderr.isatty()) if progress is None else not progress, file=sys.stderr)
    with_depth = 0
    for i in bar:
        frame = sequence[i]
        records[i] = record(frame, pipeline.process(frame))
        with_depth += records[i].has_depth
        bar.set_postfix(depth=f"{with_depth}/{i + 1}")
    if backfill and pipeline.settings.points == "sfm":
        for i, (frame, res) in _backfill(sequence, pipeline, records, n).items():
            res.extra["backfilled"] = True
            res.reason = f"offline backfill, paired with a later keyframe; {res.reason}".rstrip("; ")
            records[i] = record(frame, res)

    summary = RunSummary(
        frames_in_sequence=n_total,
        frames_processed=n,
        frames_with_depth=sum(r.has_depth for r in records.values()),
        status_counts={},
        seconds=round(time.perf_counter() - t_start, 2),
        disparity_kind=getattr(pipeline.disparity_source, "kind", ""),
    )
    for r in records.values():
        summary.status_counts[r.status] = summary.status_counts.get(r.status, 0) + 1
    ordered = [records[i] for i in range(n)]
    sfm_metrics = [r.metrics for r in ordered if r.metrics is not None]
    oracle_metrics = [r.oracle for r in ordered if r.oracle is not None]
    point_rows = [r.points for r in ordered if r.points is not None]
    if sfm_metrics:
        from .metrics import average_metrics

        summary.metrics[source] = average_metrics(sfm_metrics).to_json()
        if oracle_metrics:
            summary.metrics["oracle"] = average_metrics(oracle_metrics).to_json()
    if point_rows:
        summary.point_accuracy = _aggregate_points(point_rows)
    if exporter is not None:  # issue 13: previews, merged map, thumbnails need the whole run
        summary.outputs = exporter.finish(sequence, [r.json for r in ordered]).to_json()
    # frames.jsonl and metrics.json appear only now, complete, after every frame succeeded
    if sequence.has_gt_depth:
        write_bytes_atomic(out_dir / "metrics.json", (json.dumps(summary.to_json(), indent=2) + "\n").encode())
    write_bytes_atomic(out_dir / "frames.jsonl", "".join(json.dumps(r.json) + "\n" for r in ordered).encode())
    return summary


def _record(frame, res: FrameResult, has_gt: bool, depth_dir: Path, sigma_dir: Path | None,
            min_eval_depth: float, max_eval_depth: float, point_accuracy_fn) -> _FrameRecord:
    """Write one frame's depth (and sigma) PNG, evaluate it, and keep its JSON line."""
    from .metrics import compute_metrics, oracle_fit
    from .rescale import depth_sigma_map, metric_depth

    rec = _FrameRecord(json={}, status=res.status.value, has_depth=res.depth is not None)
    if res.depth is not None:
        write_depth_png(depth_dir / f"{frame.stem}.png", res.depth)
        if sigma_dir is not None:
            write_depth_png(sigma_dir / f"{frame.stem}.png", depth_sigma_map(res.disparity, res.fit))
    gt = frame.gt_depth() if has_gt else None
    if gt is not None and res.depth is not None:
        rec.metrics = compute_metrics(res.depth, gt, min_depth=min_eval_depth, max_depth=max_eval_depth)
        res.extra["abs_rel"] = round(float(rec.metrics.abs_rel), 5)
        res.extra["delta1"] = round(float(rec.metrics.delta1), 5)
        ofit = oracle_fit(res.disparity, gt, min_depth=min_eval_depth, max_depth=max_eval_depth)
        if ofit.ok:
            rec.oracle = compute_metrics(metric_depth(res.disparity, ofit), gt, min_depth=min_eval_depth,
                                         max_depth=max_eval_depth)
            res.extra["oracle_abs_rel"] = round(float(rec.oracle.abs_rel), 5)
    if gt is not None and point_accuracy_fn is not None and res.points_uv is not None and len(res.points_uv):
        rec.points = point_accuracy_fn(res.points_uv, res.points_depth, gt)
        res.extra.update(_point_json(rec.points))
    rec.json = res.to_json()
    return rec


def _backfill(sequence: Sequence, pipeline: Pipeline, records: dict, n: int) -> dict:
    """Results with depth for the leading frames that had none, from a backward pass.

    The leading frames are those before the first frame with depth whose failure is about
    pairing or points (not a missing disparity). A fresh pipeline with the same settings
    processes frames ``last .. 0`` in reverse order, where ``last`` lies ``2 * buffer_size``
    frames beyond the last leading frame, so each leading frame meets keyframes from its
    future. Returns ``{index: (frame, FrameResult)}`` for the frames that now have depth.
    """
    first_ok = next((i for i in range(n) if records[i].has_depth), None)
    if first_ok is None or first_ok == 0:
        return {}
    lead = [i for i in range(first_ok) if records[i].status != "no_disparity"]
    if not lead:
        return {}
    backward = Pipeline(pipeline.settings, pipeline.pose_source, pipeline.disparity_source)
    last = min(n - 1, lead[-1] + 2 * pipeline.settings.pairing.buffer_size)
    out = {}
    for i in range(last, -1, -1):
        frame = sequence[i]
        res = backward.process(frame)
        if i in lead and res.depth is not None:
            out[i] = (frame, res)
    return out


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
    if summary.outputs.get("counts"):  # issue 13
        lines.append("also wrote: " + ", ".join(f"{k} {v}" for k, v in summary.outputs["counts"].items()))
    for note in summary.outputs.get("notes", []):
        lines.append(f"note: {note}")
    if summary.disparity_kind == "simulated":
        lines.append("note: the disparity of this sequence is SIMULATED (not a Depth Anything prediction)")
    return "\n".join(lines)
