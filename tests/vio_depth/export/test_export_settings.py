"""Export flags parsing and the best / median / worst frame selection."""

import pytest

from vio_core.errors import SettingsError
from vio_depth.export import ExportSettings, PlySettings, parse_frame_list, parse_ply_spec, select_frames


def test_ply_spec_items_accumulate():
    s = parse_ply_spec(["sparse", "dense:8"])
    assert s == PlySettings(sparse=True, dense_stride=8)
    assert parse_ply_spec("dense").dense_stride == 4 and not parse_ply_spec("dense").sparse
    s = parse_ply_spec("sparse,dense:2", frames="0,5:20:5")
    assert s.dense_frames == (0, 5, 10, 15) and s.wants_dense(10) and not s.wants_dense(11)
    assert not PlySettings().any and not ExportSettings().any and ExportSettings(npy=True).any


@pytest.mark.parametrize("spec", ["mesh", "dense:0", "dense:x", "sparse,,"])
def test_bad_ply_specs_say_what_is_valid(spec):
    with pytest.raises(SettingsError, match="dense|stride"):
        parse_ply_spec(spec)


def test_frame_lists():
    assert parse_frame_list("3, 1,1") == (1, 3)
    assert parse_frame_list("0:10:4") == (0, 4, 8)
    for bad in ("", "a", "-1", "0:10:0", "5:2"):
        with pytest.raises(SettingsError):
            parse_frame_list(bad)
    with pytest.raises(SettingsError, match="dense"):
        parse_ply_spec("sparse", frames="1,2")


def _rec(i, status="ok", **kw):
    return {"frame": i, "stem": f"{i:06d}", "status": status, **kw}


def test_selection_by_abs_rel_then_fallback_criteria():
    recs = [_rec(0, "no_pair"), _rec(1, abs_rel=0.03), _rec(2, abs_rel=0.01), _rec(3, abs_rel=0.02),
            _rec(4, "fallback_previous_fit", abs_rel=0.09), _rec(5, "too_few_points", abs_rel=0.001)]
    sel = select_frames(recs)
    assert sel.criterion == "abs_rel"
    assert {k: r["frame"] for k, r in sel.frames.items()} == {"best": 2, "median": 3, "worst": 4}
    no_gt = [_rec(0, r2=0.5, inliers=10), _rec(1, r2=0.9, inliers=5)]
    sel = select_frames(no_gt)
    assert sel.criterion == "r2" and sel.frames["best"]["frame"] == 1
    assert list(sel.frames) == ["best", "worst"]  # two frames: the median is the best one, shown once
    assert select_frames([_rec(0, inliers=3)]).criterion == "inliers"
    assert select_frames([_rec(0, "no_pair")]) is None
