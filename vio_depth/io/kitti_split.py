"""KITTI split files (the Eigen test split): which frames of which raw drives to evaluate.

Two line formats are read, one entry per line (blank lines and ``#`` comments skipped):

* Monodepth2's ``splits/eigen/test_files.txt`` (697 lines)::

      2011_09_26/2011_09_26_drive_0002_sync 0000000069 l

  drive folder relative to the KITTI raw root, frame number, ``l`` (camera 2, left colour)
  or ``r`` (camera 3, right colour);
* BTS / ZoeDepth / the paper's code (``kitti_eigen_test_files_with_gt.txt``, 652 lines
  with ground truth)::

      2011_09_26/2011_09_26_drive_0002_sync/image_02/data/0000000069.png 2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000069.png 721.5377

  the image path (camera from ``image_02`` / ``image_03``, frame from the file name); the
  ground-truth path (or ``None``) and the focal length are ignored.

:func:`resolve_split` groups the entries per (drive, camera) under a KITTI raw root and
:func:`frame_indices` maps frame numbers to indices of the opened
:class:`~vio_depth.io.kitti.KittiRawSequence`, so an evaluation runs exactly those frames.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from vio_core.errors import InputError, SequenceFormatError

from .tables import read_text_table

_DRIVE_RE = re.compile(r"^(\d{4}_\d{2}_\d{2})/(\d{4}_\d{2}_\d{2}_drive_\d{4}_sync)$")
_IMAGE_RE = re.compile(r"^(\d{4}_\d{2}_\d{2})/(\d{4}_\d{2}_\d{2}_drive_\d{4}_sync)/image_0([23])/data/(\d+)\.(png|jpg)$")
_SIDES = {"l": 2, "r": 3}


@dataclass(frozen=True)
class SplitEntry:
    """One line of a split file.

    Attributes:
        drive: drive folder relative to the KITTI raw root (``2011_09_26/2011_09_26_drive_0002_sync``).
        frame: frame number (``0000000069`` -> 69).
        camera: KITTI camera index (2 = left colour, 3 = right colour).
        line: 1-based line number in the split file.
    """

    drive: str
    frame: int
    camera: int
    line: int

    @property
    def stem(self) -> str:
        """Image file stem of the frame (``0000000069``)."""
        return f"{self.frame:010d}"


def parse_split_fields(tokens, path, line: int) -> SplitEntry | None:
    """Parse the whitespace-separated fields of one line (None when only a comment is left).

    Raises:
        SequenceFormatError: a malformed entry (file and line named).
    """
    tokens = list(tokens)
    for k, t in enumerate(tokens):  # a trailing "# comment"
        if t.startswith("#"):
            tokens = tokens[:k]
            break
    if not tokens:
        return None

    def drive_of(date: str, drive: str) -> str:
        if not drive.startswith(date):
            raise SequenceFormatError(path, f"drive {drive!r} is not in date folder {date!r}", line=line)
        return f"{date}/{drive}"

    m = _IMAGE_RE.match(tokens[0].lstrip("/"))
    if m:
        date, drive, cam, frame, _ = m.groups()
        return SplitEntry(drive_of(date, drive), int(frame), int(cam), line)
    m = _DRIVE_RE.match(tokens[0].strip("/"))
    if m and len(tokens) == 3 and tokens[1].isdigit() and tokens[2].lower() in _SIDES:
        return SplitEntry(drive_of(m.group(1), m.group(2)), int(tokens[1]), _SIDES[tokens[2].lower()], line)
    raise SequenceFormatError(
        path, "expected '<date>/<date>_drive_NNNN_sync <frame> <l|r>' or "
              f"'<date>/<drive>/image_0[23]/data/<frame>.png [...]', got {' '.join(tokens)!r}", line=line)


def read_split_file(path) -> list[SplitEntry]:
    """All entries of a split file, in file order (read with :func:`~vio_depth.io.tables.read_text_table`).

    Raises:
        SequenceFormatError: unreadable file, a malformed line (file and line named), a
            duplicated entry, or no entry at all.
    """
    table = read_text_table(path, "split", layout="<drive> <frame> <l|r>, or <image path> [...]", allow_empty=True)
    entries, seen = [], {}
    for fields, line in zip(table.rows, table.lines, strict=True):
        e = parse_split_fields(fields, table.path, line)
        if e is None:
            continue
        key = (e.drive, e.frame, e.camera)
        if key in seen:
            raise SequenceFormatError(table.path, f"duplicate of line {seen[key]}: {e.drive} {e.stem} "
                                                  f"camera {e.camera}", line=line)
        seen[key] = line
        entries.append(e)
    if not entries:
        raise SequenceFormatError(table.path, "split file has no entries")
    return entries


@dataclass(frozen=True)
class SplitDrive:
    """The entries of one drive and camera: ``path`` of the drive folder, ``camera``,
    ``frames`` (frame numbers, file order) and their ``lines`` in the split file."""

    drive: str
    path: Path
    camera: int
    frames: tuple[int, ...]
    lines: tuple[int, ...]


def resolve_split(entries, kitti_root, split_path=None) -> list[SplitDrive]:
    """Group entries per (drive, camera), in order of first appearance, under ``kitti_root``.

    Raises:
        InputError: a drive folder is missing under ``kitti_root`` (the message names the
            split file line that asks for it).
    """
    root = Path(kitti_root)
    groups: dict[tuple[str, int], list[SplitEntry]] = {}
    for e in entries:
        groups.setdefault((e.drive, e.camera), []).append(e)
    out = []
    for (drive, cam), es in groups.items():
        folder = root / drive
        if not folder.is_dir():
            where = f"{split_path}:{es[0].line}: " if split_path is not None else ""
            raise InputError(f"{where}drive folder {folder} does not exist (KITTI raw root {root})")
        out.append(SplitDrive(drive, folder, cam, tuple(e.frame for e in es), tuple(e.line for e in es)))
    return out


def frame_indices(sequence, drive: SplitDrive, split_path=None) -> list[int]:
    """Indices in ``sequence`` (the opened drive) of ``drive.frames``, in split order.

    Raises:
        SequenceFormatError: a frame has no image in the drive (split file and line named).
    """
    by_stem = {sequence.frame(i).stem: i for i in range(len(sequence))}
    out = []
    for frame, line in zip(drive.frames, drive.lines):
        idx = by_stem.get(f"{frame:010d}")
        if idx is None:
            raise SequenceFormatError(split_path if split_path is not None else drive.path,
                                      f"frame {frame:010d} of {drive.drive} (camera {drive.camera}) has no image "
                                      f"in {drive.path / f'image_0{drive.camera}' / 'data'}", line=line)
        out.append(idx)
    return out
