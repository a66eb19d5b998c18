"""What a run keeps of each finished frame until its end: a few hundred bytes (issue 23).

The run-end outputs need something of every frame: ``frames.jsonl`` its record, the
trajectory its poses, ``metrics.json`` its metrics, the backward pass and the verdict its
status. Keeping the frame's :class:`~vio_depth.pipeline.FrameResult` (even without its maps)
and record objects cost 13 KB per frame (pairs with their point statuses and transforms,
fit masks, per-point evaluation arrays, record dicts): memory grew by 120 MiB over a
10 000-frame run (``benchmarks/bench_long_run.py``). A run now keeps, per frame (1.8 KB
measured with ``tracemalloc`` between frames 300 and 800 of the street sample ping-ponged):

* :class:`KeptFrame`: status, whether it has depth, and the poses its points stage used
  (:class:`~vio_depth.run.trajectory.PosedFrame`);
* its record as zlib-compressed JSON (:func:`pack_record`; 780 of 1 700 bytes on the street
  sample);
* its evaluation without the per-point arrays (:func:`slim_evaluation`).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, replace

import numpy as np

from ..evaluation import FrameEvaluation
from ..pipeline import FrameResult, FrameStatus
from .trajectory import PosedFrame

_NO_POINTS = np.zeros(0, dtype=bool)
_NO_DEPTHS = np.zeros(0, dtype=np.float64)


@dataclass(frozen=True)
class KeptFrame:
    """A finished frame as the run keeps it (see the module docstring).

    Attributes:
        status: the frame's :class:`~vio_depth.pipeline.FrameStatus`.
        has_depth: whether it got metric depth.
        posed: the poses its points stage used (for the trajectory).
    """

    status: FrameStatus
    has_depth: bool
    posed: PosedFrame

    @classmethod
    def of(cls, result: FrameResult) -> "KeptFrame":
        return cls(result.status, bool(result.has_depth), PosedFrame.of(result))


def slim_evaluation(evaluation: FrameEvaluation | None) -> FrameEvaluation | None:
    """``evaluation`` without its per-point arrays (the run-end aggregates need only the
    per-frame figures)."""
    if evaluation is None or evaluation.points is None:
        return evaluation
    return replace(evaluation, points=replace(evaluation.points, evaluated=_NO_POINTS, gt_depth=_NO_DEPTHS))


def pack_record(record: dict) -> bytes:
    """A frame record (JSON form) as compressed bytes; :func:`unpack_record` gives it back."""
    return zlib.compress(json.dumps(record).encode(), 6)


def unpack_record(packed: bytes) -> str:
    """The JSON text of a record packed by :func:`pack_record` (one line)."""
    return zlib.decompress(packed).decode()


__all__ = ["KeptFrame", "pack_record", "slim_evaluation", "unpack_record"]
