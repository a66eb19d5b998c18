"""Float depth .npy: exact float32 round trip, invalid values as NaN."""

import numpy as np
import pytest

from vio_core.errors import InputError, ShapeError
from vio_depth.export import read_depth_npy, write_depth_npy


def test_round_trip_is_bit_exact_with_nan_invalid(tmp_path):
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 300.0, (37, 53)).astype(np.float32)  # beyond the PNG's 256 m cap
    depth[rng.random(depth.shape) < 0.1] = np.nan
    write_depth_npy(tmp_path / "d.npy", depth)
    back = read_depth_npy(tmp_path / "d.npy")
    assert back.dtype == np.float32 and back.shape == depth.shape
    assert np.array_equal(back, depth, equal_nan=True)
    assert np.array_equal(back.view(np.uint32)[np.isfinite(depth)], depth.view(np.uint32)[np.isfinite(depth)])


def test_zero_negative_and_inf_become_nan_and_float64_is_cast(tmp_path):
    depth = np.array([[1.25, 0.0, -2.0], [np.inf, 3.0000001, np.nan]])
    write_depth_npy(tmp_path / "d.npy", depth)
    back = read_depth_npy(tmp_path / "d.npy")
    assert np.isnan(back[[0, 0, 1, 1], [1, 2, 0, 2]]).all()
    assert back[0, 0] == np.float32(1.25) and back[1, 1] == np.float32(3.0000001)


def test_bad_inputs_fail_cleanly(tmp_path):
    with pytest.raises(ShapeError):
        write_depth_npy(tmp_path / "d.npy", np.ones(5))
    with pytest.raises(InputError):
        write_depth_npy(tmp_path / "d.png", np.ones((2, 2)))
    np.save(tmp_path / "i.npy", np.ones((2, 2), np.int32))
    with pytest.raises(InputError, match="float32"):
        read_depth_npy(tmp_path / "i.npy")
    assert not list(tmp_path.glob(".*partial"))
