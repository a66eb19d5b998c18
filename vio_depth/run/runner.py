"""Run the pipeline over a sequence: process every frame, evaluate, write the outputs.

See :class:`~vio_depth.run.outputs.RunOutputs` for what is written and
docs/frames_schema.md for the records.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import replace
from typing import Iterable

from tqdm import tqdm

from matchers import Features
from vio_core.errors import InputError

from .._version import __version__
from ..disparity import DisparityKind
from ..evaluation import FrameEvaluation, aggregate_point_accuracy, average_metrics, evaluate_frame
from ..export import RunExporter
from ..frame import Frame
from ..io import Sequence
from ..pipeline import FrameResult, FrameStatus, Pipeline, PreparedFrame
from ..report import build_report
from .config import RunSettings, config_to_dict
from .folder import OutputFolder, OutputMode
from .kept import KeptFrame, pack_record, slim_evaluation, unpack_record
from .ranges import check_settings
from .outputs import RunOutputs
from .output_poses import OutputPoses
from .overlap import (
    OrderedWriter,
    Prefetcher,
    TorchThreads,
    blas_threads,
    opencv_threads,
    overlap_opencv_threads,
    prefetch_workers,
)
from .pose_calibration import calibrate_run_poses, calibrated_sequence
from .record import FrameRecord, RunHeader, frame_record
from .resume import ResumeError, ResumePlan, plan_run, record_difference
from .sinks import FrameSink, SinkFactory
from .summary import RunSummary, summary_of_folder
from .timing import timing_summary
from .trajectory import run_trajectory
from .verdict import judge_run

log = logging.getLogger(__name__)


def run_header(sequence: Sequence, pipeline: Pipeline, settings: RunSettings, command: list[str] | None) -> RunHeader:
    """The :class:`RunHeader` of a run (version, command line, sequence, every setting)."""
    kind = getattr(pipeline.disparity_source, "kind", "")
    return RunHeader(
        vio_depth_version=__version__,
        command=command,
        sequence={"root": str(sequence.root), "format": sequence.format_name, "name": sequence.name,
                  "frames": len(sequence)},
        settings=config_to_dict(pipeline.settings, settings),
        disparity_kind=getattr(kind, "value", str(kind)),
    )


def run_sequence(sequence: Sequence, pipeline: Pipeline, out_dir, settings: RunSettings = RunSettings(), *,
                 progress: bool | None = None, command: list[str] | None = None,
                 mode: OutputMode | str = OutputMode.NEW, inputs: Iterable = (), overlap: bool = True,
                 sinks: Iterable[SinkFactory] = ()) -> RunSummary:
    """Process ``sequence`` (or its first ``settings.max_frames`` frames) and write outputs to ``out_dir``.

    Everything is written into a staging folder next to ``out_dir`` and moved into place
    at the end (:mod:`vio_depth.run.folder`); an interrupted run can be continued with
    ``mode="resume"`` (:mod:`vio_depth.run.resume`).

    Args:
        sequence: an open sequence (:func:`vio_depth.io.open_sequence`).
        pipeline: a fresh :class:`~vio_depth.pipeline.Pipeline` for it.
        out_dir: the output folder (created if missing; see ``mode`` when it exists).
        settings: :class:`RunSettings`.
        progress: show a progress bar (None = only when stderr is a terminal).
        command: the command line to record (the CLI passes ``sys.argv``).
        mode: ``"new"`` (refuse an ``out_dir`` holding a run), ``"overwrite"`` (replace it
            atomically at the end) or ``"resume"`` (continue an interrupted run).
        inputs: further paths the run reads (disparity folder, model, config file):
            ``out_dir`` may not be, lie in or contain them, nor the sequence folder.
        overlap: prepare the next frames (image, features, disparity) and write the outputs
            in worker threads (:mod:`vio_depth.run.overlap`: with SIFT, one prefetch thread per
            core up to 4), with OpenCV's own thread pool reduced to the cores left over
            (:func:`~vio_depth.run.overlap.overlap_opencv_threads`);
            False runs everything in this thread, one stage after the other. Both give
            byte-identical outputs.
        sinks: factories of further consumers of every frame (:mod:`vio_depth.run.sinks`:
            the ROS / MCAP output, a Rerun view), each called with the staging folder.

    Returns:
        :class:`RunSummary` (also written to ``metrics.json`` with ground truth);
        ``resumed_frames`` says how many frames were replayed (-1: nothing to resume).

    Raises:
        OutputFolderError: ``out_dir`` cannot be used (before anything is written).
        ResumeError: the interrupted run differs from this one.
        InputError: unreadable inputs; ``out_dir`` is untouched and the partial run stays
            in the staging folder for ``mode="resume"``.
    """
    check_settings(pipeline.settings, settings)  # API callers too: every setting within its documented range
    folder = OutputFolder(out_dir, mode, inputs=[sequence.root, *inputs])
    n_total = len(sequence)
    n = n_total if not settings.max_frames else min(n_total, settings.max_frames)
    header = run_header(sequence, pipeline, settings, command)
    stems = [sequence.frame(i).stem for i in range(n)]
    first_of: dict[str, int] = {}
    for i, stem in enumerate(stems):
        if stem in first_of:
            raise InputError(f"{sequence.root}: frames {first_of[stem]} and {i} share the image name {stem!r}; "
                             "their outputs would overwrite each other")
        first_of[stem] = i
    plan = plan_run(folder, header.to_json(), stems)
    if plan.complete:
        log.info("%s already holds this finished run: nothing to resume", folder.out)
        summary = summary_of_folder(folder.out)
        summary.resumed_frames = -1
        return summary
    frame_sinks: list[FrameSink] = []
    try:
        frame_sinks = [make(folder.staging) for make in sinks]
        workers = _prefetch_workers(pipeline) if overlap else 1
        calibration = calibrate_run_poses(sequence, pipeline, settings, n)  # --calibrate-poses: before any frame
        with opencv_threads(overlap_opencv_threads(workers) if overlap else None), \
                blas_threads(1 if overlap else None), \
                TorchThreads(1 if overlap and workers > 1 else None) as torch_threads:
            summary = _run(calibrated_sequence(sequence, calibration, n), pipeline, folder, settings, header, plan,
                           progress, n, overlap, workers, torch_threads, frame_sinks, calibration.to_json())
        folder.commit()
    except BaseException:
        for sink in frame_sinks:
            sink.abort()
        folder.release()
        raise
    if summary.report:
        summary.report = str(folder.out / "report" / "index.html")
    return summary


def _prefetch_workers(pipeline: Pipeline) -> int:
    """Prefetch threads for ``pipeline``: several when its preparation may run concurrently
    (a matcher whose ``extract`` is thread-safe, no model inference, which uses every core
    by itself)."""
    matcher = pipeline.matcher
    concurrent = (matcher is None or getattr(matcher, "concurrent_extract", False)) and \
        getattr(pipeline.disparity_source, "kind", None) != DisparityKind.MODEL
    return prefetch_workers(concurrent)


def _prepare(sequence: Sequence, pipeline: Pipeline, i: int, features: Features | None = None) -> PreparedFrame:
    """Frame ``i`` through the pipeline's stateless stages (timed: ``load`` and the stages)."""
    t = time.perf_counter()
    frame = sequence[i]
    load = time.perf_counter() - t
    prepared = pipeline.prepare(frame, features)
    prepared.timings["load"] = load
    return prepared


def _run(sequence: Sequence, pipeline: Pipeline, folder: OutputFolder, settings: RunSettings, header: RunHeader,
         plan: ResumePlan, progress: bool | None, n: int, overlap: bool, workers: int = 1,
         torch_threads: TorchThreads | None = None, sinks: list[FrameSink] = (),
         pose_calibration: dict | None = None) -> RunSummary:
    """The frame loop (replaying the journaled frames first), the backward pass and the run-end
    outputs, all written into ``folder.staging``; ``torch_threads`` is polled after each frame
    (a matcher may load torch during the run); ``pose_calibration`` goes into ``metrics.json``."""
    out_dir = folder.staging
    outputs = RunOutputs(out_dir, uncertainty=settings.uncertainty)
    export = settings.export if not settings.report else replace(settings.export, thumbnails=True)
    exporter = RunExporter(out_dir, export) if export.any else None
    t_start = time.perf_counter()
    evaluate = settings.evaluate and sequence.has_gt_depth
    evaluate_points = not pipeline.settings.points.uses_ground_truth  # reference points come from the GT
    poses = OutputPoses(sequence, pipeline, n)  # the outputs see the run's own poses only

    def finish_frame(frame: Frame, res: FrameResult, write: bool = True) -> tuple[FrameRecord, FrameEvaluation | None]:
        t = time.perf_counter()
        if write:
            outputs.write_frame(res)
        if exporter is not None:
            exporter.add_frame(frame, res, write=write)
        for sink in sinks:  # replayed frames too: a sink's file is written anew by a resumed run
            sink.add_frame(frame, res)
        res.timings["write"] = time.perf_counter() - t
        evaluation = None
        if evaluate:
            t = time.perf_counter()
            gt = frame.gt_depth()
            if gt is not None:
                evaluation = evaluate_frame(gt, res.depth, res.disparity, res.points_uv, res.points_depth,
                                            min_depth=settings.min_eval_depth, max_depth=settings.max_eval_depth,
                                            points=evaluate_points)
            res.timings["evaluation"] = time.perf_counter() - t
        return frame_record(res, evaluation), evaluation

    # every frame until the run's end, in a few hundred bytes each (run/kept.py): flat memory
    results: dict[int, FrameResult | KeptFrame] = {}
    done: dict[int, tuple[bytes, FrameEvaluation | None]] = {}

    def write_job(i: int, frame: Frame, res: FrameResult, journal: bool = True):
        """The writer's job for frame ``i``: its files, evaluation and record, then its journal line."""
        replay = i < plan.start and journal
        frame = poses.output_frame(frame, res)  # here, in frame order: the run's pose of a frame chains on earlier ones

        def job() -> None:
            record, evaluation = finish_frame(frame, res, write=not replay)
            record = record.to_json()
            if replay:
                diff = record_difference(plan.records[i], record)
                if diff:
                    raise ResumeError(f"{folder.out}: cannot resume, replaying frame {i} ({frame.stem}) gave another "
                                      f"result than the interrupted run ({diff}); give --overwrite to start over")
            elif journal:
                folder.append(record)
            done[i] = pack_record(record), slim_evaluation(evaluation)
            results[i] = KeptFrame.of(res)
        return job

    bar = tqdm(range(n), desc=f"vio-depth {sequence.name}", unit="frame",
               disable=(not sys.stderr.isatty()) if progress is None else not progress, file=sys.stderr)
    with_depth = 0
    if plan.start:
        log.info("resuming %s: replaying frames 0-%d, then continuing", folder.out, plan.start - 1)
    writer = OrderedWriter(threaded=overlap)
    t_backfill = 0.0
    backfill = settings.backfill and pipeline.points is not None
    # the backward pass re-uses the features of the first frames (bounded: see _keep_features)
    features: dict[int, Features] = {}
    first_ok = None
    try:
        with Prefetcher(lambda i: _prepare(sequence, pipeline, i), range(n), workers + 1, threaded=overlap,
                        workers=workers) as frames:
            for i in bar:
                prepared = frames.get()
                res = pipeline.process_prepared(prepared)
                if torch_threads is not None:
                    torch_threads.poll()
                results[i] = res
                writer.submit(write_job(i, prepared.frame, res))
                with_depth += res.has_depth
                first_ok = i if first_ok is None and res.has_depth else first_ok
                if backfill and _keep_features(i, first_ok, pipeline.settings.pairing.buffer_size):
                    features[i] = prepared.features
                bar.set_postfix(depth=f"{with_depth}/{i + 1}")
        if backfill:
            t_backfill = time.perf_counter()
            back = backfill_leading_frames(sequence, pipeline, results, n, overlap=overlap, features=features,
                                           workers=workers)
            features.clear()
            for i, (frame, res) in back.items():
                res.backfilled = True
                res.reason = f"offline backfill, paired with a later keyframe; {res.reason}".rstrip("; ")
                results[i] = res
                writer.submit(write_job(i, frame, res, journal=False))
            t_backfill = time.perf_counter() - t_backfill
        writer.finish()
    except BaseException:
        writer.drain_quietly()  # the frames already handed over are completed and journaled
        raise

    evaluations = [done[i][1] for i in range(n)]
    summary = RunSummary(
        frames_in_sequence=len(sequence),
        frames_processed=n,
        frames_with_depth=sum(results[i].has_depth for i in range(n)),
        status_counts={},
        seconds=round(time.perf_counter() - t_start, 2),
        disparity_kind=header.disparity_kind,
        run=header.to_json(),
        resumed_frames=plan.start,
        pose_calibration=pose_calibration,
    )
    timing_frames, verdict_records = [], []
    for i in range(n):  # one record at a time: only the small parts are collected
        r = json.loads(unpack_record(done[i][0]))
        timing_frames.append(r["timings"])
        verdict_records.append({"status": r["status"], "reason": r.get("reason", "")})
        summary.status_counts[r["status"]] = summary.status_counts.get(r["status"], 0) + 1
    dense = [e.metrics for e in evaluations if e is not None and e.metrics is not None]
    oracle = [e.oracle for e in evaluations if e is not None and e.oracle is not None]
    if dense:
        summary.metrics[str(pipeline.settings.points)] = average_metrics(dense).to_json()
        if oracle:
            summary.metrics["oracle"] = average_metrics(oracle).to_json()
    point_rows = [e.points for e in evaluations if e is not None and e.points is not None]
    if point_rows:
        summary.point_accuracy = aggregate_point_accuracy(point_rows)
    tracker = pipeline.tracker  # a pose source with its own world poses (--poses vio): its latest estimates
    world = None if tracker is None else {i: tracker.world_pose(sequence[i]) for i in range(n)}
    trajectory = run_trajectory(sequence, {i: results[i].posed for i in range(n)}, settings.rpe_delta_m, world)
    summary.trajectory = trajectory.to_json()
    for sink in sinks:
        sink.finish(sequence, trajectory.trajectory)
    if exporter is not None:  # previews, the merged map and thumbnails need the whole run
        summary.outputs = exporter.finish(sequence, [json.loads(unpack_record(done[i][0])) for i in range(n)]).to_json()
    summary.verdict = judge_run(summary, verdict_records, settings.min_depth_fraction).to_json()
    summary.seconds = round(time.perf_counter() - t_start, 2)
    summary.timings = timing_summary(timing_frames, time.perf_counter() - t_start, overlap=overlap,
                                     backfill_s=t_backfill, prefetch_workers=workers)
    # frames.jsonl, trajectory.tum and metrics.json are written last, complete, after every frame succeeded
    outputs.finish(header, (unpack_record(done[i][0]) for i in range(n)), summary, trajectory.trajectory)
    if settings.report:
        summary.report = str(build_report(out_dir, name=folder.out.name).html)
    log.info("%s: metric depth for %d of %d frames in %.1f s", sequence.name, summary.frames_with_depth, n,
             summary.seconds)
    return summary


def _keep_features(i: int, first_ok: int | None, buffer_size: int) -> bool:
    """Whether frame ``i``'s features may serve the backward pass: it reaches at most
    ``2 * buffer_size`` frames beyond the frame before the first one with depth; while no
    frame has depth yet, at most ``4 * buffer_size`` frames are kept (memory stays bounded)."""
    if first_ok is None:
        return i < 4 * buffer_size
    return i < first_ok + 2 * buffer_size


def backfill_leading_frames(sequence: Sequence, pipeline: Pipeline, results: dict, n: int, *,
                            overlap: bool = False, features: dict | None = None, workers: int = 1) -> dict:
    """Results with depth for the leading frames that had none, from a backward pass.

    The leading frames are those before the first frame with depth whose failure is about
    pairing or points (not a missing disparity). A fresh pipeline with the same settings
    processes frames ``last .. 0`` in reverse order, where ``last`` lies ``2 * buffer_size``
    frames beyond the last leading frame, so each leading frame meets keyframes from its
    future. ``results`` maps each index to anything with ``has_depth`` and ``status`` (a
    :class:`FrameResult`); ``overlap`` prepares the frames in ``workers`` worker threads;
    ``features`` maps indices to features the forward pass extracted (not extracted again). Returns
    ``{index: (frame, FrameResult)}`` for the frames that now have depth.
    """
    first_ok = next((i for i in range(n) if results[i].has_depth), None)
    if first_ok is None or first_ok == 0:
        return {}
    lead = [i for i in range(first_ok)
            if results[i].status not in (FrameStatus.NO_DISPARITY, FrameStatus.INVALID_DISPARITY,
                                         FrameStatus.CORRUPT_IMAGE)]
    if not lead:
        return {}
    backward = pipeline.fresh()
    last = min(n - 1, lead[-1] + 2 * pipeline.settings.pairing.buffer_size)
    out = {}
    features = {} if features is None else features
    with Prefetcher(lambda i: _prepare(sequence, backward, i, features.get(i)), range(last, -1, -1), workers + 1,
                    threaded=overlap, workers=workers) as frames:
        for i in range(last, -1, -1):
            prepared = frames.get()
            res = backward.process_prepared(prepared)
            if i in lead and res.depth is not None:
                out[i] = (prepared.frame, res)
    log.info("backfill: %d of %d leading frames got depth from later keyframes", len(out), len(lead))
    return out
