"""Camera: projection and back-projection are inverse, distortion round-trips, validation."""

import numpy as np
import pytest

from vio_core import Camera, InputError, ShapeError

CAM = Camera(640, 480, 500.0, 505.0, 319.5, 239.5)
DISTORTED = Camera(640, 480, 500.0, 505.0, 319.5, 239.5, (-0.28, 0.07, 1e-4, -2e-4))


def test_project_backproject_round_trip():
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-1, 1, 50), rng.uniform(0.5, 20, 50)])
    uv, z = CAM.project(p)
    np.testing.assert_allclose(z, p[:, 2])
    np.testing.assert_allclose(CAM.backproject(uv, z), p, atol=1e-9)
    # the principal point projects the optical axis
    uv0, _ = CAM.project(np.array([[0.0, 0.0, 3.0]]))
    np.testing.assert_allclose(uv0[0], [319.5, 239.5])


def test_points_behind_the_camera_get_nan_pixels():
    uv, z = CAM.project(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]))
    assert np.isnan(uv).all() and list(z) == [-1.0, 0.0]


def test_distortion_round_trip_within_a_thousandth_of_a_pixel():
    rng = np.random.default_rng(1)
    ideal = np.column_stack([rng.uniform(40, 600, 200), rng.uniform(40, 440, 200)])
    raw = DISTORTED.distort_points(ideal)
    assert np.abs(raw - ideal).max() > 5.0  # the distortion is not negligible
    np.testing.assert_allclose(DISTORTED.undistort_points(raw), ideal, atol=1e-3)
    assert np.array_equal(CAM.undistort_points(ideal), ideal)  # undistorted camera: identity


def test_in_image_and_scaled():
    uv = np.array([[0.0, 0.0], [639.0, 479.0], [639.5, 10.0], [-0.1, 5.0]])
    assert CAM.in_image(uv).tolist() == [True, True, False, False]
    half = CAM.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    # pixel-centre convention: the centre of the image stays the centre
    assert half.cx == pytest.approx((CAM.cx + 0.5) * 0.5 - 0.5)


@pytest.mark.parametrize("kwargs", [
    dict(width=0, height=480, fx=500, fy=500, cx=1, cy=1),
    dict(width=640, height=480, fx=-1, fy=500, cx=1, cy=1),
    dict(width=640, height=480, fx=500, fy=500, cx=1, cy=1, dist=(0.1, 0.2, 0.3)),
])
def test_invalid_cameras_are_refused(kwargs):
    with pytest.raises(InputError):
        Camera(**kwargs)


def test_wrong_shapes_name_the_argument():
    with pytest.raises(ShapeError, match="points_c"):
        CAM.project(np.zeros((3, 2)))
    with pytest.raises(ShapeError, match="K"):
        Camera.from_K(np.eye(2), 10, 10)


# --------------------------------------------------------------------------- issue 12: absurd distortion
@pytest.mark.parametrize("camera", [
    (640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),  # TUM Freiburg 1
    (752, 480, 458.654, 457.296, 367.215, 248.375, (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)),  # EuRoC
    (1392, 512, 959.79, 956.9, 696.02, 224.18, (-0.3728755, 0.2037299, 0.0022190, 0.0013837, -0.0723372)),  # KITTI
    (640, 256, 360.0, 360.0, 319.5, 127.5, (0.1, -0.05, 0.001, -0.001)),
])
def test_real_lens_distortions_are_accepted(camera):
    assert Camera(*camera).distortion_problem() == ""


@pytest.mark.parametrize("dist, fragment", [
    ((5.0, -3.0, 0.0, 0.0), "scales radii"),
    ((1.0, 0.0, 0.0, 0.0), "scales radii"),
    ((-2.0, 0.0, 0.0, 0.0), "folds over"),
    ((-0.5, 0.0, 0.0, 0.0), "folds over"),
    ((0.3, 40.0, 0.0, 0.0, -90.0), "folds over"),
    ((0.0, 0.0, 0.6, 0.6), "non-finite"),
    ((float("nan"), 0.0, 0.0, 0.0), "finite"),
])
def test_absurd_distortion_coefficients_are_refused(dist, fragment):
    with pytest.raises(InputError, match=fragment):
        Camera(640, 256, 360.0, 360.0, 319.5, 127.5, dist)
