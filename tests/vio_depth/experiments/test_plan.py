"""Sequence arguments (SEQ@options), frame selections, profiles and masks, KITTI split entries."""

from pathlib import Path

import pytest

from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_depth.experiments import FrameSelection, SequenceEntry, parse_sequence_arg, resolve_entry
from vio_depth.experiments.command import study_frames
from vio_depth.experiments.plan import entries_from_split

ROOT = Path(__file__).resolve().parents[3]
STREET = ROOT / "sample_sequences" / "street"
ROOM = ROOT / "sample_sequences" / "room"
SHARED = ROOT / ".." / "shared" / "data"


def test_options_override_the_defaults():
    defaults = SequenceEntry(path="", disparity="simulated", max_depth=50.0)
    e = parse_sequence_arg("data/7scenes@indoor,frames=0:120:2,max-depth=8,crop=none,name=kitchen", defaults)
    assert e.path == "data/7scenes" and e.profile == "indoor" and e.disparity == "simulated"
    assert e.frames == FrameSelection(0, 120, 2) and e.max_depth == 8.0 and e.crop == "none" and e.label == "kitchen"
    plain = parse_sequence_arg("data/user@host/seq", defaults)  # an '@' inside the path is kept
    assert plain.path == "data/user@host/seq" and plain.max_depth == 50.0


@pytest.mark.parametrize("text, error, match", [
    ("s@nowhere", SettingsError, "unknown option 'nowhere'"),
    ("s@colour=red", SettingsError, "unknown option 'colour'"),
    ("s@frames=5", SettingsError, "A:B"),
    ("s@frames=9:3", SettingsError, "start < stop"),
    ("s@disparity=model", UnknownNameError, "sequence"),
    ("s@crop=kb", UnknownNameError, "garg"),
    ("s@pairing=highway", UnknownNameError, "kitti"),
    ("s@max-depth=far", SettingsError, "not a number"),
])
def test_bad_options_are_refused(text, error, match):
    with pytest.raises(error, match=match):
        parse_sequence_arg(text)


def test_frame_selection_resolves_against_the_sequence_length():
    assert FrameSelection(2, 10, 3).resolve(100) == (2, 9, (2, 5, 8))  # stop trimmed to the last evaluated + 1
    assert FrameSelection(0, 500).resolve(7) == (0, 7, tuple(range(7)))
    assert FrameSelection(0, None, 1, (9, 3)).resolve(20) == (0, 10, (3, 9))
    with pytest.raises(InputError, match="outside"):
        FrameSelection(0, None, 1, (30,)).resolve(20)
    with pytest.raises(InputError, match="no frame"):
        FrameSelection(50, 60).resolve(20)


def test_profiles_set_caps_pairing_and_presets():
    street = resolve_entry(parse_sequence_arg(f"{STREET}@frames=0:10"))
    assert (street.mask.max_depth, street.mask.crop, street.pairing, street.paper) == (80.0, "none", "kitti", "kitti")
    room = resolve_entry(parse_sequence_arg(f"{ROOM}@indoor,frames=4:8,crop=garg"))
    assert (room.mask.max_depth, room.mask.crop, room.pairing, room.paper) == (10.0, "garg", "indoor", "indoor")
    assert (room.start, room.stop, room.evaluate) == (4, 8, (4, 5, 6, 7)) and room.has_imu
    settings = room.task_settings("/tmp/cache", seed=3)
    assert settings["mask"] == {"min_depth": 1e-3, "max_depth": 10.0, "crop": "garg"} and settings["seed"] == 3


def test_a_sequence_without_disparity_needs_the_simulated_option(tmp_path):
    kitti = SHARED / "kitti_tiny"
    if not kitti.is_dir():
        pytest.skip("../shared/data/kitti_tiny is absent")
    with pytest.raises(InputError, match="disparity=simulated"):
        resolve_entry(parse_sequence_arg(str(kitti)))
    r = resolve_entry(parse_sequence_arg(f"{kitti}@disparity=simulated"))
    assert r.format == "kitti_raw" and r.mask.crop == "garg" and r.mask.max_depth == 80.0


def test_study_frames_are_a_block_in_the_middle():
    assert study_frames(tuple(range(100)), 4) == [48, 49, 50, 51]
    assert study_frames(tuple(range(0, 20, 2)), 3) == [6, 8, 10]
    assert study_frames((3, 20, 40), 5) == [3, 20, 40]


def test_split_entries_evaluate_exactly_the_listed_frames(tmp_path):
    kitti = SHARED / "kitti_tiny"
    if not kitti.is_dir():
        pytest.skip("../shared/data/kitti_tiny is absent")
    split = tmp_path / "split.txt"
    split.write_text("2011_09_26/2011_09_26_drive_0023_sync 0000000005 l\n"
                     "2011_09_26/2011_09_26_drive_0023_sync 0000000002 l\n")
    (entry,) = entries_from_split(split, kitti, SequenceEntry(path="", disparity="simulated"))
    r = resolve_entry(entry)
    assert entry.label == "2011_09_26_drive_0023_sync" and (r.start, r.stop, r.evaluate) == (0, 6, (2, 5))
    split.write_text("2011_09_26/2011_09_26_drive_0023_sync 0000000005 r\n")
    with pytest.raises(SettingsError, match="split.txt:1: camera 3"):
        entries_from_split(split, kitti)
