"""Variant names: parsing, canonical names, groups and errors."""

import pytest

from vio_core.errors import SettingsError
from vio_depth.experiments import VariantKind, parse_variant, parse_variants, variant_groups


@pytest.mark.parametrize("text, kind, name", [
    ("oracle", VariantKind.ORACLE, "oracle"),
    (" LiDAR:16 ", VariantKind.LIDAR, "lidar:16"),
    ("sfm", VariantKind.SFM, "sfm"),
    ("sfm:sift:gt", VariantKind.SFM, "sfm"),  # defaults are left out of the canonical name
    ("sfm:imu", VariantKind.SFM, "sfm:imu"),
    ("sfm:imu:disk+lightglue", VariantKind.SFM, "sfm:disk+lightglue:imu"),
    ("sfm-no-ransac:xfeat+lighterglue", VariantKind.SFM_NO_RANSAC, "sfm-no-ransac:xfeat+lighterglue"),
    ("fixed", VariantKind.FIXED, "fixed"),
    ("paper-reference", VariantKind.PAPER_REFERENCE, "paper-reference"),
])
def test_names_parse_to_kinds_and_canonical_names(text, kind, name):
    v = parse_variant(text)
    assert v.kind == kind and v.name == name and parse_variant(v.name) == v


@pytest.mark.parametrize("text, match", [
    ("ransac", "unknown variant"),
    ("lidar:0", "N >= 1"),
    ("lidar", "N >= 1"),
    ("sfm:orb", "'orb' is not"),
    ("sfm:sift:sift", "'sift' is not"),
    ("oracle:1", "takes no options"),
])
def test_bad_names_are_refused_with_the_valid_ones(text, match):
    with pytest.raises(SettingsError, match=match):
        parse_variant(text)


def test_groups_expand_in_order_without_duplicates():
    paper = variant_groups()["paper"]
    assert paper[0] == "oracle" and "paper-reference" in paper
    assert {"lidar:1", "lidar:16", "lidar:32", "lidar:64"} <= set(paper)
    names = [v.name for v in parse_variants(["oracle,paper", "sfm"])]
    assert names == list(paper)
    assert "sfm:imu" in [v.name for v in parse_variants("all")]
    with pytest.raises(SettingsError, match="no variant"):
        parse_variants(" , ")
