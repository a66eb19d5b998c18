"""Running a sequence: the frame loop, evaluation, outputs, records and configuration files.

=================  ============================================================================
module             job
=================  ============================================================================
``config``         :class:`RunSettings`, TOML config files (``--config``, ``config --dump``)
``runner``         :func:`run_sequence`: a run from its header to its committed folder
``frame_loop``     the forward pass: every frame in order through the pipeline
``frame_writer``   :class:`FrameWriter`: each frame's files, exports, evaluation, record, journal line
``output_poses``   :class:`OutputPoses`: the run's own pose of each frame, the only one its outputs see
``backfill``       :func:`backfill_leading_frames`: the offline backward pass (:func:`replay_posed_late` before it)
``finish``         :func:`finish_run`: the summary and the outputs that need every frame
``overlap``        :class:`Prefetcher`, :class:`OrderedWriter`: the worker threads of a run
``interrupt``      :func:`deferred_interrupts`: Ctrl-C / SIGTERM raised between frames, never inside a lock
``timing``         :func:`timing_summary`: per-stage timings in ``metrics.json``
``outputs``        :class:`RunOutputs`: depth PNGs, ``frames.jsonl``, ``metrics.json``
``record``         :class:`FrameRecord`, :class:`RunHeader` (docs/frames_schema.md)
``summary``        :class:`RunSummary`, the printed table
``folder``         :class:`OutputFolder`: path checks, the staging folder, the atomic swap into place
``resume``         continuing an interrupted run: header and replay checks
``sinks``          :class:`FrameSink`: further consumers of every frame (ROS / MCAP output, Rerun view)
``verdict``        :func:`judge_run`: "nothing came out", the exit codes
``trajectory``     the camera poses the run used (``trajectory.tum``), their ATE / RPE
pose_calibration   ``--calibrate-poses``: the pre-pass, :class:`PoseCalibratedSequence`
=================  ============================================================================
"""

from .config import (RunSettings, config_from_dict, config_to_dict, dump_config, load_config, read_config,
                     resolve_config)
from .folder import OutputFolder, OutputFolderError, OutputMode, check_out_path, staging_path
from .outputs import RunOutputs
from .interrupt import Terminated, deferred_interrupts, raise_if_interrupted, raise_terminated
from .overlap import OrderedWriter, Prefetcher
from .pose_calibration import PoseCalibratedSequence, calibrate_run_poses
from .record import RECORD_SCHEMA_VERSION, FrameRecord, RunHeader, frame_record, read_frames_jsonl
from .resume import ResumeError
from .backfill import backfill_leading_frames, replay_posed_late
from .frame_writer import FrameWriter
from .output_poses import OutputPoses
from .runner import run_header, run_sequence
from .sinks import FrameSink, SinkFactory
from .summary import RunSummary, format_table, summary_of_folder
from .timing import timing_summary
from .trajectory import TrajectoryReport, run_trajectory, used_poses
from .verdict import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_NOTHING_CAME_OUT,
    EXIT_OK,
    EXIT_USAGE,
    MIN_DEPTH_FRACTION,
    RunVerdict,
    judge_run,
)

__all__ = [
    "EXIT_ERROR",
    "EXIT_INTERRUPTED",
    "EXIT_NOTHING_CAME_OUT",
    "EXIT_OK",
    "EXIT_USAGE",
    "MIN_DEPTH_FRACTION",
    "OrderedWriter",
    "OutputFolder",
    "OutputFolderError",
    "OutputMode",
    "Prefetcher",
    "RECORD_SCHEMA_VERSION",
    "ResumeError",
    "RunVerdict",
    "FrameRecord",
    "FrameSink",
    "FrameWriter",
    "OutputPoses",
    "RunHeader",
    "RunOutputs",
    "RunSettings",
    "PoseCalibratedSequence",
    "calibrate_run_poses",
    "RunSummary",
    "SinkFactory",
    "Terminated",
    "TrajectoryReport",
    "backfill_leading_frames",
    "config_from_dict",
    "config_to_dict",
    "deferred_interrupts",
    "dump_config",
    "format_table",
    "frame_record",
    "load_config",
    "raise_if_interrupted",
    "raise_terminated",
    "read_config",
    "resolve_config",
    "read_frames_jsonl",
    "replay_posed_late",
    "run_header",
    "run_sequence",
    "check_out_path",
    "judge_run",
    "staging_path",
    "summary_of_folder",
    "timing_summary",
    "run_trajectory",
    "used_poses",
]
