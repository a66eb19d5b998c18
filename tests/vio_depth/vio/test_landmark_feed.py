"""The odometry's per-frame landmark log: bounded, newest kept, scale sigma of a span."""

import math

import numpy as np

from vio_depth.landmarks import FrameLandmarks, LandmarkPoints
from vio_depth.vio.landmark_feed import KEPT_FRAMES, LandmarkLog, relative_scale_sigma


def _frame_landmarks(n: int) -> FrameLandmarks:
    pts = LandmarkPoints(np.zeros((n, 2)), np.ones(n), 0.1 * np.ones(n), np.arange(n))
    return FrameLandmarks(pts, False, "", 3 * n, float("inf"))


def test_the_log_keeps_the_newest_frames_only():
    log = LandmarkLog(3)
    for f in range(5):
        log.record(f, _frame_landmarks(f + 1), window_keyframes=2, scale_sigma=0.01)
    assert len(log) == 3 and log.get(1) is None and log.get(4).frame_id == 4
    seen = log.get(2)
    assert len(seen.points) == 3 and seen.matches == 9 and seen.scale_sigma == 0.01 and not seen.keyframe
    assert 100 <= KEPT_FRAMES <= 1000  # enough for a start's backward pass, flat memory


def test_relative_scale_sigma():
    assert relative_scale_sigma(0.02, 1.0) == 0.02
    assert relative_scale_sigma(0.0, 0.0) == 0.0  # one keyframe: no span to doubt
    assert math.isinf(relative_scale_sigma(float("inf"), 0.0))  # no window
