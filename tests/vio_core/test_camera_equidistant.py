"""Equidistant (fisheye) distortion of vio_core.Camera against the model's closed form."""

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError

# TUM-VI-like fisheye (512 x 512, ~190 deg lens): Kalibr "equidistant" coefficients
FISHEYE = Camera(512, 512, 190.98, 190.98, 254.93, 256.90, (0.0034823, 0.0007150, -0.0020532, 0.0002029),
                 model="equidistant")


def _distort_closed_form(camera: Camera, uv_ideal: np.ndarray) -> np.ndarray:
    """theta = atan(r), theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8), x_d = theta_d / r * x."""
    k1, k2, k3, k4 = camera.dist
    x = (uv_ideal[:, 0] - camera.cx) / camera.fx
    y = (uv_ideal[:, 1] - camera.cy) / camera.fy
    r = np.hypot(x, y)
    th = np.arctan(r)
    th_d = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
    s = np.where(r > 1e-12, th_d / np.maximum(r, 1e-12), 1.0)
    return np.stack([camera.fx * s * x + camera.cx, camera.fy * s * y + camera.cy], 1)


def _ideal_grid(camera: Camera, max_angle_deg: float) -> np.ndarray:
    """Ideal pixels of rays up to ``max_angle_deg`` off axis (a polar grid, plus the centre)."""
    th = np.radians(np.linspace(0.0, max_angle_deg, 12))
    ph = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    T, P = np.meshgrid(th, ph)
    r = np.tan(T.ravel())
    return np.stack([camera.fx * r * np.cos(P.ravel()) + camera.cx, camera.fy * r * np.sin(P.ravel()) + camera.cy], 1)


def test_distort_matches_the_closed_form():
    uv = _ideal_grid(FISHEYE, 70.0)
    np.testing.assert_allclose(FISHEYE.distort_points(uv), _distort_closed_form(FISHEYE, uv), atol=1e-6)


def test_undistort_inverts_distort():
    uv = _ideal_grid(FISHEYE, 70.0)  # up to 70 deg off axis: ideal radius up to 2.7 focal lengths
    raw = FISHEYE.distort_points(uv)
    back = FISHEYE.undistort_points(raw)
    # relative to the ideal radius (pixels far out on the ideal plane are large numbers)
    err = np.linalg.norm(back - uv, axis=1) / (1.0 + np.linalg.norm(uv - [FISHEYE.cx, FISHEYE.cy], axis=1))
    assert err.max() < 1e-6, err.max()


def test_fisheye_differs_from_radtan_with_the_same_numbers():
    """Same coefficients, other model: the equidistant projection compresses the periphery."""
    radtan = Camera(512, 512, FISHEYE.fx, FISHEYE.fy, FISHEYE.cx, FISHEYE.cy, FISHEYE.dist)
    uv = _ideal_grid(FISHEYE, 50.0)
    d = np.linalg.norm(FISHEYE.distort_points(uv) - radtan.distort_points(uv), axis=1)
    assert d.max() > 20.0  # pixels: tan(50 deg) vs 50 deg in radians is 0.32 focal lengths


def test_no_coefficients_is_identity_and_scaled_keeps_the_model():
    plain = Camera(100, 80, 50.0, 50.0, 49.5, 39.5, model="equidistant")
    uv = np.array([[3.0, 4.0], [90.0, 70.0]])
    assert not plain.is_distorted
    np.testing.assert_array_equal(plain.undistort_points(uv), uv)
    half = FISHEYE.scaled(0.5)
    assert half.model == "equidistant" and half.dist == FISHEYE.dist
    # the same ray distorts to the same place, in half-size pixels
    uv_full = _ideal_grid(FISHEYE, 40.0)
    uv_half = (uv_full + 0.5) * 0.5 - 0.5
    np.testing.assert_allclose(half.distort_points(uv_half), (FISHEYE.distort_points(uv_full) + 0.5) * 0.5 - 0.5,
                               atol=1e-6)


def test_invalid_model_or_coefficient_count():
    with pytest.raises(InputError, match="unknown distortion model"):
        Camera(10, 10, 5.0, 5.0, 4.5, 4.5, model="kannala")
    with pytest.raises(InputError, match="equidistant"):
        Camera(10, 10, 5.0, 5.0, 4.5, 4.5, (0.1, 0.0, 0.0, 0.0, 0.0), model="equidistant")
    assert Camera(10, 10, 5.0, 5.0, 4.5, 4.5).model == "radtan"  # the default is unchanged
