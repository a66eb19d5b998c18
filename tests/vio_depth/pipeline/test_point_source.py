"""Tests of vio_depth/pipeline/point_source.py: the ``--points`` option, parsed and sampled."""

from __future__ import annotations

import pytest

from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_depth.pipeline import PointSourceKind, PointSourceSpec, parse_points_spec


def test_parse_points_spec():
    assert parse_points_spec("sfm") == PointSourceSpec(PointSourceKind.SFM)
    assert parse_points_spec("LiDAR:16") == PointSourceSpec(PointSourceKind.LIDAR, 16)
    spec = parse_points_spec(" random:500 ")
    assert spec.kind == PointSourceKind.RANDOM and spec.count == 500 and str(spec) == "random:500"
    assert spec.uses_ground_truth and not parse_points_spec("sfm").uses_ground_truth
    with pytest.raises(UnknownNameError) as info:
        parse_points_spec("radar:4")
    assert "lidar:<beams>" in str(info.value) and "random:<count>" in str(info.value)
    assert "radar:4" in str(info.value)
    for bad in ("lidar", "lidar:", "lidar:0", "lidar:-3", "random:1.5", "random:many", "sfm:3"):
        with pytest.raises(SettingsError) as info:
            parse_points_spec(bad)
        assert "valid forms" in str(info.value)


def test_spec_sample_dispatches(banded_gt):
    gt = banded_gt
    uv, depth = parse_points_spec("lidar:1").sample(gt)
    assert set(uv[:, 1].astype(int)) == {50}
    uv, _ = parse_points_spec("random:20", seed=1).sample(gt)
    assert len(uv) == 20
    with pytest.raises(InputError):
        parse_points_spec("sfm").sample(gt)
