"""Issue 23: every numeric setting of every preset has a documented range, checked in one place."""

import dataclasses
import math
from pathlib import Path

import pytest

from vio_core.errors import SettingsError
from vio_core.ranges import numeric_fields
from vio_core.settings import override
from vio_depth.pipeline import PRESET_FAMILIES, PipelineSettings
from vio_depth.run import RunSettings
from vio_depth.run.ranges import SETTING_RANGES, check_settings, describe_ranges

DOC = Path(__file__).resolve().parents[3] / "docs" / "settings_ranges.md"


def _trees():
    yield PipelineSettings()
    yield RunSettings()
    for presets in PRESET_FAMILIES.values():
        for name in presets:
            yield presets[name]


def test_every_numeric_setting_of_every_preset_has_a_range():
    missing = sorted({key for tree in _trees() for key, _, _ in numeric_fields(tree)} - set(SETTING_RANGES))
    assert not missing, f"add a valid range for {missing} to SETTING_RANGES in vio_depth/run/ranges.py"


def test_the_defaults_and_every_preset_are_within_their_ranges():
    check_settings(PipelineSettings(), RunSettings())
    for presets in PRESET_FAMILIES.values():
        for name in presets:
            if dataclasses.is_dataclass(presets[name]):
                check_settings(presets[name])


def test_docs_list_the_table():
    doc = DOC.read_text(encoding="utf-8")
    for row in describe_ranges().splitlines()[2:]:
        field_and_range = row.split(" | ", 1)[1]  # the TOML keys depend on the presets of the day
        assert field_and_range in doc, \
            f"docs/settings_ranges.md is out of date ({field_and_range}): paste describe_ranges() into it"


@pytest.mark.parametrize("changes, path", [
    ({"rescaler": {"ransac": {"inlier_sigmas": math.inf}}}, "rescaler.ransac.inlier_sigmas"),
    ({"rescaler": {"ransac": {"min_relative_spread": math.inf}}}, "rescaler.ransac.min_relative_spread"),
    ({"triangulation": {"max_depth_m": math.inf}}, "triangulation.max_depth_m"),
    ({"matcher": {"edge_threshold": math.inf}}, "matcher.edge_threshold"),
])
def test_infinite_thresholds_are_refused(changes, path):
    """Issue 23: `[rescaler.ransac] inlier_sigmas = inf` was accepted (AbsRel 0.017 -> 0.047)."""
    with pytest.raises(SettingsError, match=path.replace(".", r"\.")):
        check_settings(override(PipelineSettings(), changes))
