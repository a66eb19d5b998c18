"""Aggregation of per-frame scores into a results row, and metrics on common frames."""

import pytest

from vio_depth.experiments import FrameScore, aggregate
from vio_depth.experiments.scores import common_frames, mean_on


def _scores():
    return [
        FrameScore(0, "no_pair", False, points=0),
        FrameScore(1, "ok", True, delta1=0.9, abs_rel=0.10, rmse=2.0, pixel_coverage=1.0, r2=0.9, points=100,
                   point_error=0.05),
        FrameScore(2, "ok", True, delta1=0.7, abs_rel=0.30, rmse=4.0, pixel_coverage=0.5, r2=0.7, points=300,
                   point_error=0.01),
        FrameScore(3, "fallback_scale_only", True, delta1=0.8, abs_rel=0.20, rmse=3.0, pixel_coverage=1.0, r2=None,
                   points=200, point_error=None),
    ]


def test_metrics_average_over_frames_with_depth_and_coverage_counts_them():
    row = aggregate(_scores(), seconds=2.0, processed=8)
    assert row["frames"] == 4 and row["frames_with_depth"] == 3 and row["coverage"] == 0.75
    assert row["delta1"] == pytest.approx(0.8) and row["abs_rel"] == pytest.approx(0.2) and row["rmse"] == 3.0
    assert row["r2"] == pytest.approx(0.8)  # median of the frames with a fit
    assert row["points_per_frame"] == 150.0  # median over all evaluated frames, also without depth
    assert row["point_error"] == pytest.approx(0.03) and row["seconds_per_frame"] == 0.25
    assert row["statuses"] == {"fallback_scale_only": 1, "no_pair": 1, "ok": 2}


def test_scores_round_trip_and_common_frames():
    s = _scores()
    assert [FrameScore.from_json(x.to_json()) for x in s] == s
    other = [FrameScore(1, "ok", True, delta1=1.0, abs_rel=0.0, rmse=0.0), FrameScore(2, "no_pair", False)]
    assert common_frames([s, other]) == {1}
    assert mean_on(s, {1, 2}) == {"frames": 2, "delta1": pytest.approx(0.8), "abs_rel": pytest.approx(0.2),
                                  "rmse": pytest.approx(3.0)}
    assert mean_on(s, set())["frames"] == 0
