"""Sequence abstraction shared by every loader, and :class:`SequenceFormat`, a loader's entry.

A :class:`Sequence` holds only light metadata (paths, timestamps, poses, IMU samples);
pixel data are read lazily when a :class:`~vio_depth.frame.Frame`'s loaders are called,
so iterating a sequence never holds more than the current frame in memory.

Each loader module defines its ``FORMAT`` (a :class:`SequenceFormat`); :mod:`.formats` lists
them in detection order, and its :func:`~vio_depth.io.open_sequence` auto-detects the format
or honours an explicit ``format=`` name.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from vio_core.camera import Camera

from ..disparity import DisparitySpec
from ..frame import Frame, ImuData


class Sequence(abc.ABC):
    """A lazily loaded image sequence with poses and optional IMU, depth and disparity.

    Attributes:
        root: the sequence folder.
        name: a short name (the folder's, or the one its metadata gives).
        camera: intrinsics of every frame.
        imu: the whole sequence's IMU samples, or None.
        disparity: the disparity the folder carries (:class:`~vio_depth.disparity.DisparitySpec`),
            or None; the disparity stage reads or simulates it.
    """

    #: format name, e.g. "native", "kitti_raw"
    format_name: str = ""
    #: why ``imu`` is None, for error messages ("" = the folder has no IMU data)
    imu_missing_reason: str = ""
    #: what kind of poses the dataset gives, for how far to trust them (a
    #: :data:`vio_depth.landmarks.POSE_PRIOR_PRESETS` name: ``exact``, ``mocap``,
    #: ``kinectfusion``, ``ins``); loaders override it
    pose_kind: str = "mocap"

    def __init__(self, root: Path, name: str, camera: Camera, imu: ImuData | None = None,
                 disparity: DisparitySpec | None = None):
        self.root = Path(root)
        self.name = name
        self.camera = camera
        self.imu = imu
        self.disparity = disparity

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def frame(self, index: int) -> Frame:
        """Frame ``index`` (cheap: reads no pixels)."""

    @property
    @abc.abstractmethod
    def has_gt_depth(self) -> bool: ...

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(index)
        return self.frame(index % len(self))

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r}, frames={len(self)})"


@dataclass(frozen=True)
class SequenceFormat:
    """A sequence format: its name (``--format``), whether a path is one, how to open it, a line about it."""

    name: str
    detect: Callable[[Path], bool]
    open: Callable[[Path], Sequence]
    description: str = ""
