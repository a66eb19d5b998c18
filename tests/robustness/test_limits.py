"""Issue 23: every input size is checked before decoding, and absurd values are refused at load.

Unit tests of :mod:`vio_core.limits` (hypothesis where it fits: the bracket count without a
parser must equal the parsed nesting for any document), and one end-to-end refusal per
reader: text tables, JSON, TOML, image headers, positions, IMU calibration, OXTS.
"""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vio_core.errors import SequenceFormatError, SettingsError
from vio_core.limits import (
    MAX_NESTING,
    LimitError,
    image_size_problem,
    nesting_depth,
    parse_json,
    read_json_file,
    read_limited,
    value_depth,
)
from vio_core.settings import toml_dumps, toml_loads
from vio_depth.frame import imu_calibration_problem
from vio_depth.io.kitti_oxts import read_oxts_packet
from vio_depth.io.tables import MAX_POSITION_M, read_tum_trajectory

EXAMPLES = settings(max_examples=int(os.environ.get("VIO_DEPTH_HYPOTHESIS_EXAMPLES", "200")), deadline=None,
                    derandomize=not os.environ.get("VIO_DEPTH_HYPOTHESIS_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# JSON values whose strings hold the characters that could fool a bracket count
TEXT = st.text(alphabet='[]{}"\\\',#\n ab', max_size=8)
JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers() | TEXT,
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(TEXT, inner, max_size=3),
                           max_leaves=20)


@EXAMPLES
@given(JSON_VALUES)
def test_the_bracket_count_equals_the_parsed_nesting_of_any_json(value):
    text = json.dumps(value)
    assert nesting_depth(text, "json") == value_depth(value)
    assert parse_json(text) == value


TOML_SCALARS = st.integers(-10**6, 10**6) | st.booleans() | st.text(alphabet='[]{}"\\\'#= ab', max_size=8)
TOML_TABLES = st.recursive(st.dictionaries(st.sampled_from(["a", "b", "c"]), TOML_SCALARS | st.lists(TOML_SCALARS,
                                                                                                    max_size=3),
                                           max_size=3),
                           lambda inner: st.dictionaries(st.sampled_from(["t", "u"]), inner, min_size=1, max_size=2),
                           max_leaves=12)


@EXAMPLES
@given(TOML_TABLES)
def test_toml_with_brackets_and_quotes_in_strings_reads_back(table):
    """The nesting check never refuses a document vio-depth itself writes."""
    text = toml_dumps(table)
    assert nesting_depth(text, "toml") <= value_depth(table) + 2
    assert toml_loads(text) == table


@pytest.mark.parametrize("depth", [MAX_NESTING + 1, 1000, 100000])
def test_deep_json_and_toml_are_refused_without_recursion(depth):
    with pytest.raises(LimitError, match="nested"):
        parse_json("[" * depth + "]" * depth)
    with pytest.raises(SettingsError, match="nested"):
        toml_loads("x = " + "[" * depth + "]" * depth)


def test_dotted_keys_nested_without_brackets_are_refused():
    with pytest.raises(SettingsError, match="nested"):
        toml_loads("a" + ".a" * (MAX_NESTING + 5) + " = 1")


def test_files_larger_than_the_limit_are_not_read(tmp_path):
    big = tmp_path / "big.json"
    big.write_bytes(b" " * 5000 + b"{}")
    assert read_limited(big, 10) == (None, 5002)
    with pytest.raises(LimitError, match="larger than"):
        read_json_file(big, limit=100)
    assert read_json_file(big) == {}


def test_a_text_table_larger_than_the_limit_is_one_line(mini_street, tmp_path, cli, one_line, monkeypatch):
    import vio_depth.io.tables as tables

    seq = mini_street(3)
    monkeypatch.setattr(tables, "MAX_TEXT_BYTES", 200)
    rc, _, err = cli("run", seq, "--out", tmp_path / "o")
    one_line(rc, err, "poses.txt", "a trajectory file of", "is larger than the 200 bytes vio-depth reads")


def test_a_huge_sequence_json_is_refused_before_it_is_parsed(mini_street, tmp_path, cli, one_line):
    seq = mini_street(3)
    meta = (seq / "sequence.json").read_bytes()
    (seq / "sequence.json").write_bytes(meta + b" " * (64 << 20))  # 64 MiB of trailing spaces
    rc, _, err = cli("run", seq, "--out", tmp_path / "o")
    one_line(rc, err, "sequence.json", "larger than the 64 MiB")


def test_a_config_larger_than_1_mib_is_one_line(tmp_path, cli, one_line):
    config = tmp_path / "c.toml"
    config.write_text("# " + "x" * (1 << 20) + "\n")
    rc, _, err = cli("config", "--dump", "--config", config)
    one_line(rc, err, "c.toml", "larger than the 1 MiB")


@pytest.mark.parametrize("w, h, ok", [(640, 480, True), (7680, 4320, True), (20000, 2000, True),
                                      (20001, 10, False), (16000, 16000, False), (0, 10, False)])
def test_image_size_limits(w, h, ok):
    assert (image_size_problem(w, h) == "") is ok


def test_a_frame_other_than_the_camera_size_is_refused_from_its_header(mini_street, tmp_path, cli, one_line):
    import cv2

    seq = mini_street(3)
    (seq / "images" / "000001.jpg").write_bytes(cv2.imencode(".jpg", np.zeros((100, 100, 3), np.uint8))[1].tobytes())
    rc, _, err = cli("run", seq, "--out", tmp_path / "o")
    one_line(rc, err, "000001.jpg", "image is 100x100 but the camera is 640x256 (read from its header)")


@pytest.mark.parametrize("tx, ok", [(5.5e6, True), (-9.9e7, True), (1.5e8, False), (1e300, False)])
def test_trajectory_positions_beyond_1e8_m_are_refused_naming_the_line(tmp_path, tx, ok):
    path = tmp_path / "traj.txt"
    path.write_text("# t tx ty tz qx qy qz qw\n0.0 0 0 0 0 0 0 1\n"
                    f"0.1 {tx!r} 0 0 0 0 0 1\n0.2 0 0 0 0 0 0 1\n")
    if ok:
        assert read_tum_trajectory(path)[1][1, 0, 3] == tx
    else:
        with pytest.raises(SequenceFormatError, match=r"traj\.txt:3: position .* beyond the plausible 1e\+08 m"):
            read_tum_trajectory(path)
    assert MAX_POSITION_M == 1e8


@pytest.mark.parametrize("lat, lon, alt", [(95.0, 8.4, 100.0), (49.0, 200.0, 100.0), (49.0, 8.4, 1e300)])
def test_oxts_packets_that_are_no_place_on_earth_are_refused(tmp_path, lat, lon, alt):
    values = [lat, lon, alt] + [0.0] * 27
    path = tmp_path / "0000000000.txt"
    path.write_text(" ".join(repr(v) for v in values) + "\n")
    with pytest.raises(SequenceFormatError, match="not a place on Earth"):
        read_oxts_packet(path)


FINITE_POSITIVE = st.floats(min_value=1e-9, max_value=1e3)
ANY = st.floats(allow_nan=True, allow_infinity=True)


@EXAMPLES
@given(st.tuples(ANY, FINITE_POSITIVE, FINITE_POSITIVE, FINITE_POSITIVE),
       st.lists(st.floats(-20, 20), min_size=3, max_size=3))
def test_imu_calibration_ranges(noise, gravity):
    problem = imu_calibration_problem(*noise, gravity_w=gravity)
    g = float(np.linalg.norm(gravity))
    valid = math.isfinite(noise[0]) and noise[0] > 0 and 9.7 <= g <= 9.9
    assert (problem == "") is valid, problem


def test_a_kitti_calibration_that_is_not_rigid_is_refused(tmp_path):
    from vio_depth.io.kitti_oxts import CALIB_IMU_TO_VELO, load_kitti_calibration

    drive = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti_tiny"
    calib = next(iter(sorted(drive.glob("**/calib_cam_to_cam.txt"))), None) if drive.is_dir() else None
    if calib is None:
        pytest.skip("../shared/data/kitti_tiny absent")
    import shutil

    folder = tmp_path / "calib"
    shutil.copytree(calib.parent, folder, ignore=shutil.ignore_patterns("*_drive_*"))
    path = folder / CALIB_IMU_TO_VELO
    lines = path.read_text().splitlines()
    lines = [("R: " + " ".join(["1e300"] * 9)) if ln.startswith("R:") else ln for ln in lines]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match="not a rigid calibration"):
        load_kitti_calibration(folder, camera=2)
