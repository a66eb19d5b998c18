"""PipelineSettings: one settings object per stage, presets by name, overrides from tables."""

import pytest

from matchers import LearnedMatcherSettings, SiftSettings
from vio_core import SettingsError, UnknownNameError
from vio_depth.pipeline import PointSourceKind, PointSourceSpec
from vio_depth.pipeline import PRESET_FAMILIES, TRACKER_DEFAULTS, PipelineSettings, with_tracker_defaults
from vio_depth.poses import ImuPoseSettings


def test_defaults_are_the_default_presets():
    s = PipelineSettings()
    assert s.preset_names() == {name: family.default for name, family in PRESET_FAMILIES.items()}
    assert s.points == PointSourceSpec() and s.disparity.source == "sequence"


def test_from_presets_and_points_are_normalised_once():
    s = PipelineSettings.from_presets(matcher="xfeat+lighterglue", poses="imu", pairing="indoor", points="LIDAR:16")
    assert isinstance(s.matcher, LearnedMatcherSettings) and s.matcher.extractor == "xfeat"
    assert isinstance(s.poses, ImuPoseSettings) and s.pairing.min_translation_m == 0.15
    assert s.points.kind == PointSourceKind.LIDAR and str(s.points) == "lidar:16"
    assert str(PipelineSettings(points="SFM").points) == "sfm"  # any case, one canonical name
    with pytest.raises(UnknownNameError, match="kitti"):
        PipelineSettings.from_presets(pairing="mars")


def test_from_dict_preset_then_field_overrides():
    s = PipelineSettings.from_dict({
        "matcher": {"preset": "sift", "ratio": 0.7},
        "pairing": {"preset": "indoor", "min_translation_m": 0.3},
        "rescaler": {"preset": "paper", "ransac": {"inlier_sigmas": 2.5}},
        "points": {"source": "random:50", "seed": 4},
        "min_matches": 30,
    })
    assert s.matcher == SiftSettings(ratio=0.7)
    assert s.pairing.min_translation_m == 0.3 and s.pairing.min_rotation_deg == 5.0
    assert s.rescaler.temporal is None and not s.rescaler.fallback and s.rescaler.ransac.inlier_sigmas == 2.5
    assert str(s.points) == "random:50" and s.points.seed == 4 and s.min_matches == 30
    assert PipelineSettings.from_dict({"matcher": "disk+lightglue"}).matcher.extractor == "disk"


@pytest.mark.parametrize("table, message", [
    ({"matchr": {}}, r"unknown settings table\(s\) matchr; valid: matcher"),
    ({"matcher": {"ration": 0.7}}, r"unknown setting matcher\.ration; valid: .*ratio"),
    ({"matcher": {"ratio": 1.7}}, r"ratio must be in \(0, 1\]"),
    ({"pairing": {"min_translation_m": float("nan")}}, r"pairing\.min_translation_m: NaN"),
    ({"rescaler": {"ransac": {"seed": -1.5}}}, r"rescaler\.ransac\.seed: expected an integer"),
    ({"points": {"source": "lidar:0"}}, r"positive number of beams"),
    ({"min_matches": 0}, r"min_matches"),
])
def test_invalid_tables_raise_settings_errors_naming_the_key(table, message):
    with pytest.raises(SettingsError, match=message):
        PipelineSettings.from_dict(table)


def test_to_dict_round_trips():
    s = PipelineSettings.from_presets(matcher="aliked+lightglue", pairing="ddad", rescaler="per_frame",
                                      points="lidar:32")
    assert PipelineSettings.from_dict(s.to_dict()) == s
    assert s.to_dict()["matcher"]["preset"] == "aliked+lightglue"


def _tracker_fields(s):
    return {(stage, name): getattr(getattr(s, stage), name) for stage, name, _ in TRACKER_DEFAULTS}


def test_the_tracker_brings_its_defaults_unless_they_are_set():
    """KLT: the edge guard on and no weak pairs (docs/benchmarks.md "Real time and trust,
    2026-12-06"), by preset name or by a config file, with any pairing or rescaler preset; a value
    the file sets wins; another matcher gets none of it."""
    wanted = {(stage, name): value for stage, name, value in TRACKER_DEFAULTS}
    assert wanted == {("rescaler", "max_disparity_spread"): 0.1, ("pairing", "allow_weak_pairs"): False}
    P = PipelineSettings
    klt = P.from_presets(matcher="klt", pairing="indoor", rescaler="paper")
    assert _tracker_fields(klt) == wanted and klt.pairing.min_translation_m == 0.15 and klt.rescaler.temporal is None
    assert _tracker_fields(P.from_dict({"matcher": {"preset": "klt"}, "pairing": "indoor"})) == wanted
    # a file on top of a klt base: a pairing preset chosen there replaces the stage, the defaults come back
    assert _tracker_fields(P.from_dict({"pairing": {"preset": "indoor"}}, base=P.from_presets(matcher="klt"))) == wanted
    mine = P.from_dict({"matcher": "klt", "pairing": {"allow_weak_pairs": True}, "rescaler": {"max_disparity_spread": 0.2}})
    assert mine.pairing.allow_weak_pairs is True and mine.rescaler.max_disparity_spread == 0.2
    kept = P.from_dict({"pairing": {"preset": "kitti", "allow_weak_pairs": True}}, base=P.from_presets(matcher="klt"))
    assert kept.pairing.allow_weak_pairs is True and kept.rescaler.max_disparity_spread == 0.1
    for sift in (P.from_presets(matcher="sift"), P.from_dict({"matcher": "sift", "pairing": "indoor"}), P()):
        assert sift.pairing.allow_weak_pairs is True and sift.rescaler.max_disparity_spread is None
    assert with_tracker_defaults(P()) == P()
    assert P.from_dict(klt.to_dict()) == klt  # the dump of a klt run loads back to the same settings
