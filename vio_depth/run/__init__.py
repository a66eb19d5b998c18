"""Running a sequence: the frame loop, evaluation, outputs, records and configuration files.

=================  ============================================================================
module             job
=================  ============================================================================
``config``         :class:`RunSettings`, TOML config files (``--config``, ``config --dump``)
``runner``         :func:`run_sequence`: the frame loop, the offline backfill
``outputs``        :class:`RunOutputs`: depth PNGs, ``frames.jsonl``, ``metrics.json``
``record``         :class:`FrameRecord`, :class:`RunHeader` (docs/frames_schema.md)
``summary``        :class:`RunSummary`, the printed table
``trajectory``     the camera poses the run used (``trajectory.tum``), their ATE / RPE
=================  ============================================================================
"""

from .config import RunSettings, config_from_dict, config_to_dict, dump_config, load_config
from .outputs import RunOutputs
from .record import RECORD_SCHEMA_VERSION, FrameRecord, RunHeader, frame_record, read_frames_jsonl
from .runner import backfill_leading_frames, run_header, run_sequence
from .summary import RunSummary, format_table
from .trajectory import TrajectoryReport, run_trajectory, used_poses

__all__ = [
    "RECORD_SCHEMA_VERSION",
    "FrameRecord",
    "RunHeader",
    "RunOutputs",
    "RunSettings",
    "RunSummary",
    "TrajectoryReport",
    "backfill_leading_frames",
    "config_from_dict",
    "config_to_dict",
    "dump_config",
    "format_table",
    "frame_record",
    "load_config",
    "read_frames_jsonl",
    "run_header",
    "run_sequence",
    "run_trajectory",
    "used_poses",
]
