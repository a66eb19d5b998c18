"""Frame sinks: extra consumers of a run's results (ROS bag / MCAP output, a live Rerun view).

A sink is made by a factory that receives the run's staging folder (files written there
move into ``--out`` with the rest at the end), is fed every frame in frame order from the
writer lane (again for a frame the offline backfill gave depth, and for the frames a
resumed run replays, so a resumed run's sink output equals an uninterrupted one's), and
is finished once with the run's trajectory, or aborted when the run fails.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Protocol

from ..evaluation import CameraTrajectory
from ..frame import Frame
from ..io import Sequence
from ..pipeline import FrameResult


class FrameSink(Protocol):
    """What :func:`vio_depth.run.run_sequence` calls on a sink."""

    def add_frame(self, frame: Frame, result: FrameResult) -> None:
        """One finished frame (its maps and points still attached)."""

    def finish(self, sequence: Sequence, trajectory: CameraTrajectory | None) -> object:
        """The run succeeded: ``trajectory`` is the camera poses it used (``trajectory.tum``)."""

    def abort(self) -> None:
        """The run failed: release files and connections (the run's error is raised after)."""


#: builds a sink in the run's staging folder
SinkFactory = Callable[[Path], FrameSink]

__all__ = ["FrameSink", "SinkFactory"]
