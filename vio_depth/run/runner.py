"""Run the pipeline over a sequence: :func:`run_sequence`, the entry point of a run.

A run is split along its jobs:

===================  ========================================================================
module               job
===================  ========================================================================
``runner``           :func:`run_sequence`: the header, the output folder, resume planning,
                     the thread settings; :func:`_run` puts the passes below together
``frame_loop``       the forward pass: every frame in order through the pipeline
``frame_writer``     each frame's files, exports, sinks, evaluation, record and journal line
``output_poses``     the run's own pose of each frame, the only one its outputs see
``resume``           continuing an interrupted run: what is replayed, the checks
``backfill``         the offline backward pass for the leading frames without depth
``finish``           the run's summary and the outputs that need every frame
===================  ========================================================================

See :class:`~vio_depth.run.outputs.RunOutputs` for what is written and
docs/frames_schema.md for the records.
"""

from __future__ import annotations

import logging
import time
from typing import Iterable

from vio_core.errors import InputError

from .._version import __version__
from ..disparity import DisparityKind
from ..io import Sequence
from ..pipeline import Pipeline
from .backfill import backfill_pass
from .config import RunSettings, config_to_dict
from .finish import finish_run
from .folder import OutputFolder, OutputMode
from .frame_loop import forward_pass
from .frame_writer import FrameWriter
from .interrupt import deferred_interrupts
from .overlap import (
    OrderedWriter,
    TorchThreads,
    blas_threads,
    opencv_threads,
    overlap_opencv_threads,
    prefetch_workers,
)
from .pose_calibration import calibrate_run_poses, calibrated_sequence
from .ranges import check_settings
from .record import RunHeader
from .resume import ResumePlan, plan_run
from .sinks import FrameSink, SinkFactory
from .summary import RunSummary, summary_of_folder

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
    (a matcher whose ``extract`` is thread-safe, or a tracker whose frames take turns while
    their disparity runs concurrently; no model inference, which uses every core by itself)."""
    matcher = pipeline.matcher
    concurrent = (matcher is None or getattr(matcher, "concurrent_extract", False) or pipeline.tracked is not None) \
        and getattr(pipeline.disparity_source, "kind", None) != DisparityKind.MODEL
    return prefetch_workers(concurrent)


def _run(sequence: Sequence, pipeline: Pipeline, folder: OutputFolder, settings: RunSettings, header: RunHeader,
         plan: ResumePlan, progress: bool | None, n: int, overlap: bool, workers: int = 1,
         torch_threads: TorchThreads | None = None, sinks: list[FrameSink] = (),
         pose_calibration: dict | None = None) -> RunSummary:
    """The run inside its folder: the forward pass (replaying the journaled frames first,
    :mod:`.frame_loop`), the backward pass (:mod:`.backfill`) and the run-end outputs
    (:mod:`.finish`), all written into ``folder.staging`` by one :class:`FrameWriter`
    (:mod:`.frame_writer`) in frame order; ``torch_threads`` is polled after each frame (a
    matcher may load torch during the run); ``pose_calibration`` goes into ``metrics.json``."""
    frames_out = FrameWriter(sequence, pipeline, folder, settings, plan, n, sinks)
    t_start = time.perf_counter()
    if plan.start:
        log.info("resuming %s: replaying frames 0-%d, then continuing", folder.out, plan.start - 1)
    writer = OrderedWriter(threaded=overlap)
    backfill_s = 0.0
    backfill = settings.backfill and pipeline.points is not None
    try:
        with deferred_interrupts():  # Ctrl-C / SIGTERM between frames, never inside a worker's lock
            # the backward pass re-uses the features of the first frames (bounded: see keep_features),
            # except a tracking matcher's: it follows the frames backwards again (its forward track ids
            # would not join the backward ones, and tracking costs little)
            features = forward_pass(sequence, pipeline, n, frames_out, writer, progress=progress, overlap=overlap,
                                    workers=workers, torch_threads=torch_threads,
                                    keep=backfill and pipeline.tracked is None)
            pipeline.finish_sequence()  # what the odometry's worker still had: poses for the backward pass
            if backfill:
                backfill_s = backfill_pass(sequence, pipeline, n, frames_out, writer, features, overlap=overlap,
                                           workers=workers)
            writer.finish()
    except BaseException:
        writer.drain_quietly()  # the frames already handed over are completed and journaled
        raise
    return finish_run(sequence, pipeline, folder, settings, header, frames_out, n, t_start=t_start,
                      resumed_frames=plan.start, overlap=overlap, workers=workers, backfill_s=backfill_s,
                      sinks=sinks, pose_calibration=pose_calibration)
