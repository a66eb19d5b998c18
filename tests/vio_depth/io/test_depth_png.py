"""16-bit depth PNG (KITTI convention: metres * 256, 0 = invalid)."""

import cv2
import numpy as np
import pytest

from vio_core.errors import InputError, SequenceFormatError, ShapeError
from vio_depth.io.depth_png import encode_depth_uint16, read_depth_png, write_depth_png


def test_round_trip_within_half_a_quantisation_step(tmp_path):
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.05, 250.0, (48, 64))
    path = tmp_path / "d.png"
    write_depth_png(path, depth)
    back = read_depth_png(path)
    assert back.dtype == np.float32 and back.shape == depth.shape
    # rounding to the nearest 1/256 m: error at most half a step (plus float32 representation)
    assert np.max(np.abs(back - depth)) <= 0.5 / 256 + 1e-4
    assert np.max(np.abs(back - depth)) > 0  # really quantised, not a float copy


def test_invalid_values_become_zero_and_stay_invalid(tmp_path):
    depth = np.array([[np.nan, 0.0, -3.0, np.inf], [1.0, 2.5, 1e-4, 400.0]])
    path = tmp_path / "d.png"
    write_depth_png(path, depth)
    back = read_depth_png(path)
    assert np.array_equal(back[0], np.zeros(4))
    assert back[1, 0] == 1.0 and back[1, 1] == 2.5
    assert back[1, 2] == pytest.approx(1 / 256)  # tiny positive depth stays valid (clipped up)
    assert back[1, 3] == pytest.approx(65535 / 256)  # beyond the range: saturates
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw[0].max() == 0 and raw[1, 3] == 65535


def test_encode_matches_kitti_convention():
    q = encode_depth_uint16(np.array([[1.0, 10.0]]))
    assert q.dtype == np.uint16 and q.tolist() == [[256, 2560]]


@pytest.mark.parametrize("bad", ["uint8", "rgb16", "garbage", "missing"])
def test_unreadable_or_wrong_type_files_name_the_file(tmp_path, bad):
    path = tmp_path / f"{bad}.png"
    if bad == "uint8":
        cv2.imwrite(str(path), np.zeros((4, 5), np.uint8))
    elif bad == "rgb16":
        cv2.imwrite(str(path), np.zeros((4, 5, 3), np.uint16))
    elif bad == "garbage":
        path.write_bytes(b"not a png at all")
    with pytest.raises(SequenceFormatError) as err:
        read_depth_png(path)
    assert err.value.path == str(path)
    assert str(path) in str(err.value)


def test_write_rejects_bad_shapes_and_extensions(tmp_path):
    with pytest.raises(ShapeError):
        write_depth_png(tmp_path / "d.png", np.zeros((2, 3, 1)))
    with pytest.raises(InputError):
        write_depth_png(tmp_path / "d.jpg", np.ones((2, 3)))


def test_float32_fast_path_and_fast_png_store_the_same_values(tmp_path):
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.0, 300.0, (40, 50)).astype(np.float32)
    depth[0, :6] = [np.nan, np.inf, -np.inf, -1.0, 0.0, 3e38]
    depth[1, :4] = [1e-6, 255.998, 127.99805, 0.001953125]  # rounding at half steps and the range ends
    fast = encode_depth_uint16(depth)  # float32, scale 256: the exact float32 path
    reference = encode_depth_uint16(depth.astype(np.float64))
    assert fast.dtype == np.uint16 and np.array_equal(fast, reference)
    assert np.array_equal(encode_depth_uint16(depth, scale=1000.0), encode_depth_uint16(depth.astype(np.float64),
                                                                                          scale=1000.0))
    write_depth_png(tmp_path / "small.png", depth)
    write_depth_png(tmp_path / "fast.png", depth, fast=True)
    assert np.array_equal(read_depth_png(tmp_path / "fast.png"), read_depth_png(tmp_path / "small.png"))
    assert (tmp_path / "fast.png").read_bytes() != (tmp_path / "small.png").read_bytes()
