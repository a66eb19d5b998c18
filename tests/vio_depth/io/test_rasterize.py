"""rasterize_depth: the nearest point per pixel; points projecting outside (or to infinity) are dropped."""

import warnings

import numpy as np

from vio_core.camera import Camera
from vio_depth.io.rasterize import rasterize_depth

CAM = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)


def test_nearest_point_per_pixel_wins():
    pts = np.array([[0.0, 0.0, 4.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.61, 0.0, 1.0]])
    d = rasterize_depth(pts, CAM)
    assert d[24, 32] == 2.0  # (31.5, 23.5) rounds to column 32, row 24
    assert d[24, 62] == 1.0  # 31.5 + 50 * 0.61 = 62.0
    assert np.count_nonzero(d) == 2


def test_points_just_in_front_of_the_camera_are_dropped_without_warnings():
    pts = np.array([[1.0, 1.0, 1e-320], [-1.0, 0.5, 1e-310], [0.0, 0.0, 2.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = rasterize_depth(pts, CAM)
    assert np.count_nonzero(d) == 1 and d[24, 32] == 2.0
