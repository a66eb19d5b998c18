"""The edge guard: points whose disparity varies a lot around them (depth edges) are not fitted."""

import numpy as np
import pytest

from vio_core import SettingsError
from vio_depth.rescale import RescalerSettings, disparity_spread


def step_map(w: int = 40, h: int = 30) -> np.ndarray:
    """Disparity 1.0 left of column 20, 2.0 from it on."""
    d = np.ones((h, w), np.float32)
    d[:, 20:] = 2.0
    return d


def test_spread_is_zero_on_flat_ground_and_large_on_an_edge():
    d = step_map()
    uv = np.array([[5.0, 10.0], [19.4, 10.0], [21.0, 10.0], [30.0, 15.0]])
    s = disparity_spread(d, uv, 3)
    np.testing.assert_allclose(s[[0, 3]], 0.0)
    assert s[1] == pytest.approx(1.0)  # nearest pixel column 19 (1.0): (2 - 1) / 1
    assert s[2] == pytest.approx(0.5)  # column 21 (2.0): (2 - 1) / 2


def test_spread_is_infinite_near_the_border_invalid_pixels_and_bad_positions():
    d = step_map()
    d[5, 5] = np.nan
    uv = np.array([[1.0, 10.0], [6.0, 6.0], [np.nan, 3.0], [10.0, 10.0]])
    s = disparity_spread(d, uv, 2)
    assert np.isinf(s[:3]).all() and s[3] == 0.0


def test_settings_refuse_a_bad_guard():
    with pytest.raises(SettingsError):
        RescalerSettings(max_disparity_spread=0.0)
    with pytest.raises(SettingsError):
        RescalerSettings(spread_radius_px=0)
