"""The end of a run: its summary and the outputs that need every frame.

Once every frame is written (forward pass and backward pass), :func:`finish_run` builds the
:class:`~vio_depth.run.summary.RunSummary` from the frames' records and evaluations (status
counts, averaged metrics, point accuracy), the run's trajectory and its ATE / RPE
(:mod:`vio_depth.run.trajectory`), closes the sinks, writes the exports that need the whole
run (previews, the merged map, thumbnails), judges the run (:mod:`vio_depth.run.verdict`),
sums the timings (:mod:`vio_depth.run.timing`) and writes ``frames.jsonl``,
``trajectory.tum``, ``metrics.json`` and the report -- last, complete, after every frame
succeeded.
"""

from __future__ import annotations

import logging
import time

from ..evaluation import aggregate_point_accuracy, average_metrics
from ..io import Sequence
from ..pipeline import Pipeline
from ..report import build_report
from .config import RunSettings
from .folder import OutputFolder
from .frame_writer import FrameWriter
from .record import RunHeader
from .sinks import FrameSink
from .summary import RunSummary
from .timing import timing_summary
from .trajectory import run_trajectory
from .verdict import judge_run

log = logging.getLogger(__name__)


def summarise_frames(frames_out: FrameWriter, n: int, summary: RunSummary, point_source: str) -> tuple[list, list]:
    """Fill ``summary``'s status counts, averaged metrics (row ``point_source`` and ``oracle``)
    and point accuracy from the records and evaluations of frames ``0 .. n-1``; returns their
    ``(timings, {status, reason})`` lists for :func:`timing_summary` and :func:`judge_run`."""
    evaluations = [frames_out.evaluation(i) for i in range(n)]
    timing_frames, verdict_records = [], []
    for i in range(n):  # one record at a time: only the small parts are collected
        r = frames_out.record(i)
        timing_frames.append(r["timings"])
        verdict_records.append({"status": r["status"], "reason": r.get("reason", "")})
        summary.status_counts[r["status"]] = summary.status_counts.get(r["status"], 0) + 1
    dense = [e.metrics for e in evaluations if e is not None and e.metrics is not None]
    oracle = [e.oracle for e in evaluations if e is not None and e.oracle is not None]
    if dense:
        summary.metrics[point_source] = average_metrics(dense).to_json()
        if oracle:
            summary.metrics["oracle"] = average_metrics(oracle).to_json()
    point_rows = [e.points for e in evaluations if e is not None and e.points is not None]
    if point_rows:
        summary.point_accuracy = aggregate_point_accuracy(point_rows)
    return timing_frames, verdict_records


def finish_run(sequence: Sequence, pipeline: Pipeline, folder: OutputFolder, settings: RunSettings,
               header: RunHeader, frames_out: FrameWriter, n: int, *, t_start: float, resumed_frames: int,
               overlap: bool, workers: int, backfill_s: float, sinks: list[FrameSink] = (),
               pose_calibration: dict | None = None) -> RunSummary:
    """The run's summary and run-end outputs, written into ``folder.staging`` (module docstring).

    Args:
        frames_out: the run's writer, every frame's job done.
        t_start: ``time.perf_counter()`` at the run's start. resumed_frames: frames replayed.
        overlap / workers / backfill_s: how the run ran, for the timings.
        pose_calibration: the ``--calibrate-poses`` result for ``metrics.json``, or None.
    """
    results = frames_out.results
    summary = RunSummary(
        frames_in_sequence=len(sequence),
        frames_processed=n,
        frames_with_depth=sum(results[i].has_depth for i in range(n)),
        status_counts={},
        seconds=round(time.perf_counter() - t_start, 2),
        disparity_kind=header.disparity_kind,
        run=header.to_json(),
        resumed_frames=resumed_frames,
        pose_calibration=pose_calibration,
    )
    timing_frames, verdict_records = summarise_frames(frames_out, n, summary, str(pipeline.settings.points))
    tracker = pipeline.tracker  # a pose source with its own world poses (--poses vio): its latest estimates
    world = None if tracker is None else {i: tracker.world_pose(sequence[i]) for i in range(n)}
    trajectory = run_trajectory(sequence, {i: results[i].posed for i in range(n)}, settings.rpe_delta_m, world)
    summary.trajectory = trajectory.to_json()
    for sink in sinks:
        sink.finish(sequence, trajectory.trajectory)
    if frames_out.exporter is not None:  # previews, the merged map and thumbnails need the whole run
        summary.outputs = frames_out.exporter.finish(sequence, [frames_out.record(i) for i in range(n)]).to_json()
    summary.verdict = judge_run(summary, verdict_records, settings.min_depth_fraction).to_json()
    summary.seconds = round(time.perf_counter() - t_start, 2)
    summary.timings = timing_summary(timing_frames, time.perf_counter() - t_start, overlap=overlap,
                                     backfill_s=backfill_s, prefetch_workers=workers)
    # frames.jsonl, trajectory.tum and metrics.json are written last, complete, after every frame succeeded
    frames_out.outputs.finish(header, (frames_out.record_json(i) for i in range(n)), summary, trajectory.trajectory)
    if settings.report:
        summary.report = str(build_report(folder.staging, name=folder.out.name).html)
    log.info("%s: metric depth for %d of %d frames in %.1f s", sequence.name, summary.frames_with_depth, n,
             summary.seconds)
    return summary
