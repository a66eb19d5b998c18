"""Sequence abstraction and the format registry shared by every loader.

A :class:`Sequence` holds only light metadata (paths, timestamps, poses, IMU samples);
pixel data are read lazily when a :class:`~vio_depth.types.Frame`'s loaders are called,
so iterating a sequence never holds more than the current frame in memory.

Loaders register themselves with :func:`register_format`; :func:`open_sequence`
auto-detects the format or honours an explicit ``format=`` name.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from vio_core.camera import Camera
from vio_core.errors import InputError, lookup
from ..types import Frame, ImuData


class Sequence(abc.ABC):
    """A lazily loaded image sequence with poses and optional IMU/depth/disparity."""

    #: format name, e.g. "native", "kitti_raw"
    format_name: str = ""

    def __init__(self, root: Path, name: str, camera: Camera, imu: ImuData | None = None):
        self.root = Path(root)
        self.name = name
        self.camera = camera
        self.imu = imu

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def frame(self, index: int) -> Frame:
        """Frame ``index`` (cheap: reads no pixels)."""

    @property
    @abc.abstractmethod
    def has_gt_depth(self) -> bool: ...

    @property
    def has_disparity(self) -> bool:
        return False

    @property
    def disparity_is_simulated(self) -> bool:
        return False

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
    name: str
    detect: Callable[[Path], bool]
    open: Callable[[Path], Sequence]
    description: str = ""


_FORMATS: dict[str, SequenceFormat] = {}


def register_format(fmt: SequenceFormat) -> SequenceFormat:
    _FORMATS[fmt.name] = fmt
    return fmt


def available_formats() -> list[str]:
    _load_builtin_formats()
    return sorted(_FORMATS)


def _load_builtin_formats() -> None:
    # Importing the loader modules registers them.
    from . import native  # noqa: F401

    try:  # real-data loaders (issue 4) may not be present in every checkout
        from . import kitti, sevenscenes, tum  # noqa: F401
    except ImportError:
        pass


def open_sequence(path, format: str | None = None) -> Sequence:
    """Open the sequence at ``path``; auto-detect its format unless ``format`` is given.

    Raises:
        InputError: ``path`` is missing or no format recognises it.
        UnknownNameError: ``format`` is not a registered format name.
    """
    _load_builtin_formats()
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    if format is not None:
        return lookup("sequence format", format, _FORMATS).open(path)
    for fmt in _FORMATS.values():
        if fmt.detect(path):
            return fmt.open(path)
    raise InputError(
        f"{path}: not a recognised sequence folder (formats: {', '.join(sorted(_FORMATS))}; "
        "see docs/sequence_format.md)"
    )
