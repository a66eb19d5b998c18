"""Writing a run's outputs: depth (and 1-sigma) PNGs per frame, then frames.jsonl, trajectory.tum
and metrics.json.

Every file is written under a temporary name and renamed into place when complete, so an
interrupted run never leaves a half-written file (and the whole folder is a staging folder
that is moved into ``--out`` only at the end, :mod:`vio_depth.run.folder`); ``frames.jsonl``, ``trajectory.tum`` and
``metrics.json`` appear only when the whole run succeeded.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Iterable

from ..evaluation import CameraTrajectory, write_trajectory_tum
from ..io.depth_png import write_bytes_atomic, write_chunks_atomic, write_depth_png
from ..pipeline import FrameResult
from ..rescale import depth_sigma_map
from .record import FrameRecord, RunHeader
from .summary import RunSummary


class RunOutputs:
    """The output folder of one run.

    Layout: ``depth/<stem>.png`` (uint16, metres x 256, 0 = invalid), with ``uncertainty``
    also ``uncertainty/<stem>.png`` (1-sigma of the depth from the fit's covariance, same
    encoding), ``frames.jsonl``, ``trajectory.tum`` (the camera poses the run used, TUM
    format, camera-to-world: :mod:`vio_depth.run.trajectory`) and ``metrics.json``. The PNGs
    are encoded for speed (:data:`~vio_depth.io.depth_png.FAST_PNG_PARAMS`).
    """

    def __init__(self, out_dir, *, uncertainty: bool = False):
        self.root = Path(out_dir)
        self.depth_dir = self.root / "depth"
        self.sigma_dir = self.root / "uncertainty" if uncertainty else None
        for folder in (self.depth_dir, self.sigma_dir):
            if folder is not None:
                folder.mkdir(parents=True, exist_ok=True)

    def write_frame(self, result: FrameResult) -> None:
        """The frame's depth PNG (and 1-sigma PNG); nothing for a frame without depth."""
        if result.depth is None:
            return
        write_depth_png(self.depth_dir / f"{result.stem}.png", result.depth, fast=True)
        if self.sigma_dir is not None:
            write_depth_png(self.sigma_dir / f"{result.stem}.png", depth_sigma_map(result.disparity, result.fit),
                            fast=True)

    def finish(self, header: RunHeader, records: Iterable[FrameRecord | str], summary: RunSummary | None,
               trajectory: CameraTrajectory | None = None) -> None:
        """``frames.jsonl`` (header line, then the records in order: :class:`FrameRecord` objects
        or their JSON lines, streamed to the file), ``trajectory.tum`` and ``metrics.json`` when
        given."""
        if trajectory is not None:
            write_trajectory_tum(self.root / "trajectory.tum", trajectory)
        if summary is not None:
            write_bytes_atomic(self.root / "metrics.json", (json.dumps(summary.to_json(), indent=2) + "\n").encode())
        lines = (r if isinstance(r, str) else json.dumps(r.to_json()) for r in records)
        write_lines_atomic(self.root / "frames.jsonl", itertools.chain([json.dumps(header.to_json())], lines))


def write_lines_atomic(path: Path, lines: Iterable[str]) -> None:
    """Write ``lines`` (each ended by a newline) to ``path`` via a temporary file in the same
    folder and a rename, one line at a time (a long run's frames.jsonl is never in memory)."""
    write_chunks_atomic(path, ((line + "\n").encode("utf-8") for line in lines))
