"""rotation_free_flow: the image motion a pair shows once the camera's rotation is removed
(the initialisation's parallax test and the rest test), on projected points of known truth."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import ShapeError
from vio_depth.vio.matching import rotation_free_flow

CAM = Camera(640, 480, 500.0, 505.0, 319.5, 239.5)


def _project(points_c: np.ndarray) -> np.ndarray:
    return np.column_stack([CAM.fx * points_c[:, 0] / points_c[:, 2] + CAM.cx,
                            CAM.fy * points_c[:, 1] / points_c[:, 2] + CAM.cy])


def _pair(R_prev_cur, t_prev_cur, seed=0):
    """Keypoints of 200 points 2-6 m ahead in the previous and the current camera."""
    rng = np.random.default_rng(seed)
    p_prev = np.column_stack([rng.uniform(-1.5, 1.5, 200), rng.uniform(-1, 1, 200), rng.uniform(2, 6, 200)])
    p_cur = (p_prev - t_prev_cur) @ R_prev_cur  # points in the current camera: R^T (p - t)
    return _project(p_cur), _project(p_prev)


def test_a_pure_rotation_shows_no_motion_once_removed():
    R = Rotation.from_euler("xyz", [2.0, -3.0, 1.0], degrees=True).as_matrix()
    kp_cur, kp_prev = _pair(R, np.zeros(3))
    assert np.median(np.linalg.norm(kp_cur - kp_prev, axis=1)) > 10  # the raw motion is large
    assert rotation_free_flow(kp_cur, kp_prev, CAM, CAM, R) < 1e-6


def test_a_translation_shows_its_parallax():
    """1 cm sideways at 2-6 m: f * 0.01 / z, i.e. 0.8-2.5 px (median about 1.3 px)."""
    R = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()
    kp_cur, kp_prev = _pair(R, np.array([0.01, 0.0, 0.0]))
    flow = rotation_free_flow(kp_cur, kp_prev, CAM, CAM, R)
    assert 0.8 < flow < 2.5
    assert rotation_free_flow(kp_cur, kp_prev, CAM, CAM, np.eye(3)) > 5  # the rotation not removed


def test_shapes_are_checked():
    with pytest.raises(ShapeError):
        rotation_free_flow(np.zeros((5, 2)), np.zeros((4, 2)), CAM, CAM, np.eye(3))
