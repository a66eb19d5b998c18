"""Config resolution: preset flags, a config file's tables, and the matcher that follows the pose source."""

import pytest

from matchers import KltSettings, SiftSettings
from vio_core.errors import InputError, SettingsError
from vio_depth.pipeline import TRACKER_DEFAULTS, PipelineSettings, default_matcher_preset, default_points_spec
from vio_depth.pipeline.settings import POSE_PRESETS
from vio_depth.run import load_config, read_config, resolve_config


@pytest.mark.parametrize("poses, expected", [("gt", KltSettings), ("imu", SiftSettings),
                                             ("imu_real_mav", SiftSettings), ("vio", KltSettings),
                                             ("vio_offline", SiftSettings), ("vio_realtime", KltSettings)])
def test_the_matcher_follows_the_pose_source_when_nothing_names_one(poses, expected):
    assert default_matcher_preset(POSE_PRESETS[poses]) == ("klt" if expected is KltSettings else "sift")
    by_flag, _ = resolve_config({"poses": poses})
    by_file, _ = resolve_config({}, {"poses": {"preset": poses}})
    assert type(by_flag.matcher) is expected and type(by_file.matcher) is expected
    assert by_flag == by_file
    if expected is KltSettings:  # and brings the tracker's defaults
        for stage, name, value in TRACKER_DEFAULTS:
            assert getattr(getattr(by_flag, stage), name) == value


def test_a_named_matcher_wins_over_the_pose_source():
    assert type(resolve_config({"matcher": "sift"})[0].matcher) is SiftSettings
    assert type(resolve_config({}, {"matcher": {"preset": "sift"}})[0].matcher) is SiftSettings
    assert type(resolve_config({}, {"matcher": "sift"})[0].matcher) is SiftSettings
    assert type(resolve_config({"poses": "vio", "matcher": "klt"})[0].matcher) is KltSettings
    assert type(resolve_config({}, default_matcher="sift")[0].matcher) is SiftSettings  # --guided-matching


def test_a_matcher_table_without_a_preset_refines_the_default_matcher():
    s, _ = resolve_config({}, {"matcher": {"max_tracks": 300}, "rescaler": {"max_disparity_spread": 0.2}})
    assert isinstance(s.matcher, KltSettings) and s.matcher.max_tracks == 300
    assert s.rescaler.max_disparity_spread == 0.2  # the file's own value beats the tracker's default
    assert s.pairing.allow_weak_pairs is False
    s, _ = resolve_config({"poses": "vio_offline"}, {"matcher": {"ratio": 0.7}})
    assert isinstance(s.matcher, SiftSettings) and s.matcher.ratio == 0.7
    with pytest.raises(SettingsError, match=r"c\.toml: unknown setting matcher\.ratio.*default matcher, klt with "
                                            r"these poses; add preset = \"sift\""):
        resolve_config({}, {"matcher": {"ratio": 0.7}}, source="c.toml")


def test_presets_that_disagree_and_other_errors_name_the_file():
    with pytest.raises(SettingsError, match="--matcher klt and the config file's \\[matcher\\] preset 'sift' disagree"):
        resolve_config({"matcher": "klt"}, {"matcher": {"preset": "sift"}})
    with pytest.raises(SettingsError, match=r"^c\.toml: unknown settings table\(s\) bogus"):
        resolve_config({}, {"bogus": {}}, source="c.toml")
    with pytest.raises(SettingsError, match=r"^c\.toml: rescaler"):  # found while choosing the matcher
        resolve_config({}, {"rescaler": {"max_disparity_spread": -1.0}}, source="c.toml")


def test_read_config_and_load_config(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[poses]\npreset = "vio"\n[matcher]\nratio = 0.7\n')
    assert read_config(path) == {"poses": {"preset": "vio"}, "matcher": {"ratio": 0.7}}
    s, _ = load_config(path)  # applies on the library's defaults (sift), whatever the pose source
    assert isinstance(s.matcher, SiftSettings) and s.matcher.ratio == 0.7
    with pytest.raises(InputError, match="config file not found"):
        read_config(tmp_path / "missing.toml")
    path.write_text("[matcher\n")
    with pytest.raises(SettingsError, match="c.toml"):
        read_config(path)


@pytest.mark.parametrize("name", ["vio", "vio_realtime"])
def test_vio_is_the_odometry_with_the_window_in_a_worker_and_klt(name):
    s, _ = resolve_config({"poses": name})
    assert s.poses.backend.kind == "process" and s.poses.backend.lag_frames == 4
    assert isinstance(s.matcher, KltSettings) and s.pairing.allow_weak_pairs is False
    assert s.preset_names()["poses"] == "vio"  # the former name resolves to the same settings
    # the inline window, asked for in a file, keeps klt unless a matcher is named: vio_offline is sift
    inline = {"poses": {"backend": {"kind": "inline"}}}
    assert isinstance(resolve_config({"poses": name}, inline)[0].matcher, SiftSettings)
    assert isinstance(resolve_config({"poses": "vio_offline"})[0].matcher, SiftSettings)
    # the worker, asked for in a file under vio_offline, brings klt too; a named sift stays
    worker = {"poses": {"backend": {"kind": "process"}}}
    assert isinstance(resolve_config({"poses": "vio_offline"}, worker)[0].matcher, KltSettings)
    assert isinstance(resolve_config({"poses": "vio_offline", "matcher": "sift"}, worker)[0].matcher, SiftSettings)


@pytest.mark.parametrize("poses, expected", [("gt", "sfm"), ("imu", "sfm"), ("vio_offline", "sfm"), ("vio", "vio"),
                                                 ("vio_realtime", "vio")])
def test_the_points_follow_the_pose_source_when_nothing_names_them(poses, expected):
    """``vio`` (the camera-rate configuration) reads the odometry's own landmarks instead
    of matching and triangulating every frame a second time; the other pose sources pair two-view."""
    assert default_points_spec(POSE_PRESETS[poses]) == expected
    by_flag, _ = resolve_config({"poses": poses})
    by_file, _ = resolve_config({}, {"poses": {"preset": poses}})
    assert by_flag.points.kind.value == expected and by_file == by_flag
    seeded, _ = resolve_config({"poses": poses}, {"points": {"seed": 7}})  # a table without a source refines it
    assert seeded.points.kind.value == expected and seeded.points.seed == 7
    named, _ = resolve_config({"poses": poses}, {"points": {"source": "landmarks"}})
    assert named.points.kind.value == "landmarks"


@pytest.mark.parametrize("poses", [None, *POSE_PRESETS])
def test_for_pose_source_builds_what_the_command_line_builds(poses):
    """The library's ``PipelineSettings.for_pose_source`` gives the command line's settings for the
    same preset names (the matcher and points following the pose source); ``from_presets`` keeps
    sift and two-view points whatever the poses."""
    flags = {} if poses is None else {"poses": poses}
    for extra in ({}, {"pairing": "indoor"}, {"matcher": "sift"}):
        expected, _ = resolve_config({**flags, **extra})
        assert PipelineSettings.for_pose_source(poses, **extra) == expected, (poses, extra)
    named, _ = resolve_config(flags, {"points": "landmarks"})  # (on the command line: --points)
    assert PipelineSettings.for_pose_source(poses, points="landmarks") == named
    plain = PipelineSettings.from_presets(**flags)
    assert isinstance(plain.matcher, SiftSettings) and plain.points.kind.value == "sfm"
    with pytest.raises(ValueError, match="vio_realtime"):
        PipelineSettings.for_pose_source("vio_fast")
