"""The sequence formats, in detection order, and opening a sequence by format or by detection.

:data:`FORMATS` is an explicit table of every loader's ``FORMAT``: adding a loader means adding
it here. :func:`open_sequence` tries them in this order; the order matters where two could
claim one folder (an ASL folder or a bag before the folder layouts that look only at files).
"""

from __future__ import annotations

from pathlib import Path

from vio_core.errors import InputError, lookup

from .asl import FORMAT as ASL
from .bag import FORMAT as BAG
from .base import Sequence, SequenceFormat
from .ddad import FORMAT as DDAD
from .kitti import FORMAT as KITTI_RAW
from .native import FORMAT as NATIVE
from .sevenscenes import FORMAT as SEVEN_SCENES
from .tum import FORMAT as TUM_RGBD

#: every format, in detection order
FORMATS: tuple[SequenceFormat, ...] = (ASL, BAG, DDAD, KITTI_RAW, NATIVE, SEVEN_SCENES, TUM_RGBD)

_BY_NAME: dict[str, SequenceFormat] = {fmt.name: fmt for fmt in FORMATS}


def available_formats() -> list[str]:
    """The format names (``--format``), sorted."""
    return sorted(_BY_NAME)


def open_sequence(path, format: str | None = None) -> Sequence:
    """Open the sequence at ``path``; auto-detect its format unless ``format`` is given.

    Raises:
        InputError: ``path`` is missing or no format recognises it.
        UnknownNameError: ``format`` is not a format name (the valid ones are listed).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    if format is not None:
        return lookup("sequence format", format, _BY_NAME).open(path)
    for fmt in FORMATS:
        if fmt.detect(path):
            return fmt.open(path)
    raise InputError(
        f"{path}: not a recognised sequence folder (formats: {', '.join(available_formats())}; "
        "see docs/sequence_format.md)"
    )
