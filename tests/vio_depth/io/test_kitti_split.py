"""Tests of vio_depth/io/kitti_split.py: Eigen split files -> (drive, frame, camera) -> sequence indices."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from vio_core.errors import InputError, SequenceFormatError
from vio_depth.io.kitti_split import SplitEntry, frame_indices, read_split_file, resolve_split

SHARED = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
D2 = "2011_09_26/2011_09_26_drive_0002_sync"
D9 = "2011_09_26/2011_09_26_drive_0009_sync"


def test_both_line_formats_comments_and_blank_lines(tmp_path):
    split = tmp_path / "test_files.txt"
    split.write_text(
        "# Eigen test split (excerpt)\n"
        f"{D2} 0000000069 l\n"
        "\n"
        f"{D2} 0000000054 r   # right camera\n"
        f"{D2}/image_02/data/0000000042.png 2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000042.png 721.5377\n"
        f"{D9}/image_03/data/0000000016.png None 721.5377\n"
    )
    entries = read_split_file(split)
    assert entries == [SplitEntry(D2, 69, 2, 2), SplitEntry(D2, 54, 3, 4), SplitEntry(D2, 42, 2, 5),
                       SplitEntry(D9, 16, 3, 6)]
    assert entries[0].stem == "0000000069"


@pytest.mark.parametrize("line", [
    f"{D2} 0000000069",                       # no side
    f"{D2} 0000000069 x",                     # unknown side
    f"{D2} frame l",                          # not a number
    "2011_09_26_drive_0002_sync 0000000069 l",  # no date folder
    f"{D2}/image_01/data/0000000042.png",     # grey camera
    "2011_09_28/2011_09_26_drive_0002_sync 1 l",  # drive not in its date folder
    "2011_09_28/2011_09_26_drive_0002_sync/image_02/data/0000000001.png",  # same, image form
])
def test_malformed_lines_name_file_and_line(tmp_path, line):
    split = tmp_path / "split.txt"
    split.write_text(f"{D2} 0000000001 l\n{line}\n")
    with pytest.raises(SequenceFormatError) as err:
        read_split_file(split)
    assert str(err.value).startswith(f"{split}:2: ")


def test_duplicates_and_empty_files_are_refused(tmp_path):
    split = tmp_path / "split.txt"
    split.write_text(f"{D2} 0000000001 l\n{D2}/image_02/data/0000000001.png\n")
    with pytest.raises(SequenceFormatError, match=r"split.txt:2: duplicate of line 1"):
        read_split_file(split)
    split.write_text("# nothing\n\n")
    with pytest.raises(SequenceFormatError, match="no entries"):
        read_split_file(split)
    with pytest.raises(SequenceFormatError, match="split file not found"):
        read_split_file(tmp_path / "missing.txt")


def test_resolve_groups_per_drive_and_camera_in_file_order(tmp_path):
    for d in (D2, D9):
        (tmp_path / d).mkdir(parents=True)
    entries = [SplitEntry(D2, 69, 2, 1), SplitEntry(D9, 3, 2, 2), SplitEntry(D2, 54, 2, 3), SplitEntry(D2, 54, 3, 4)]
    drives = resolve_split(entries, tmp_path)
    assert [(d.drive, d.camera, d.frames, d.lines) for d in drives] == [
        (D2, 2, (69, 54), (1, 3)), (D9, 2, (3,), (2,)), (D2, 3, (54,), (4,))]
    assert drives[0].path == tmp_path / D2
    with pytest.raises(InputError, match=r"split.txt:1: drive folder .*drive_0005_sync does not exist"):
        resolve_split([SplitEntry("2011_09_26/2011_09_26_drive_0005_sync", 1, 2, 1)], tmp_path, "split.txt")


@dataclass
class _Frame:
    stem: str


class _Drive:
    """Stand-in for an opened drive: frames 0000000010 .. 0000000014."""

    def __len__(self):
        return 5

    def frame(self, i):
        return _Frame(f"{10 + i:010d}")


def test_frame_indices_map_numbers_to_sequence_positions(tmp_path):
    (tmp_path / D2).mkdir(parents=True)
    drive = resolve_split([SplitEntry(D2, 13, 2, 7), SplitEntry(D2, 10, 2, 8)], tmp_path)[0]
    assert frame_indices(_Drive(), drive) == [3, 0]
    missing = resolve_split([SplitEntry(D2, 99, 2, 9)], tmp_path)[0]
    with pytest.raises(SequenceFormatError, match=r"^split.txt:9: frame 0000000099 .* has no image"):
        frame_indices(_Drive(), missing, "split.txt")


@pytest.mark.shared_data
def test_split_runs_on_kitti_tiny(tmp_path):
    root = SHARED / "kitti_tiny"
    if not root.is_dir():
        pytest.skip("../shared/data/kitti_tiny is absent")
    from vio_depth.io import open_sequence

    split = tmp_path / "split.txt"
    split.write_text("2011_09_26/2011_09_26_drive_0023_sync 0000000005 l\n"
                     "2011_09_26/2011_09_26_drive_0023_sync 0000000002 l\n")
    (drive,) = resolve_split(read_split_file(split), root, split)
    seq = open_sequence(drive.path)
    idx = frame_indices(seq, drive, split)
    assert [seq.frame(i).stem for i in idx] == ["0000000005", "0000000002"]
