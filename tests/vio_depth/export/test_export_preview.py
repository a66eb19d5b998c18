"""Colourised previews: colours invert to the depth they show; invalid pixels are marked."""

import numpy as np
import pytest

from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_depth.export import (
    PreviewSettings,
    available_colormaps,
    colormap_lut,
    depth_from_rgb,
    depth_percentiles,
    depth_preview,
    depth_to_index,
    error_preview,
    index_to_depth,
    parse_depth_range,
    read_png_rgb,
    relative_error,
    run_depth_range,
    write_png_rgb,
)
from vio_depth.export.preview import encode_png_indexed, encode_png_rgb


@pytest.mark.parametrize("name", available_colormaps() + ["coolwarm"])
def test_luts_are_invertible_rgb_tables(name):
    lut = colormap_lut(name)
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    assert len(np.unique(lut, axis=0)) >= 250  # nearly every entry distinct: colours are invertible


def test_turbo_near_is_warm_far_is_cool():
    lut = colormap_lut("turbo")
    idx, valid = depth_to_index(np.array([1.0, 100.0]), 1.0, 100.0)
    near, far = lut[idx]
    assert valid.all() and idx.tolist() == [255, 0]
    assert near[0] > near[2] and far[2] > far[0]  # red-ish near, blue-ish far


@pytest.mark.parametrize("scale", ["log", "linear"])
def test_index_round_trip_within_half_a_step(scale):
    d = np.geomspace(0.5, 80.0, 1000)
    idx, _ = depth_to_index(d, 0.5, 80.0, scale)
    back = index_to_depth(idx, 0.5, 80.0, scale)
    if scale == "log":
        step = np.log(80.0 / 0.5) / 255
        assert np.max(np.abs(np.log(back / d))) <= step / 2 + 1e-12
    else:
        assert np.max(np.abs(back - d)) <= (80.0 - 0.5) / 255 / 2 + 1e-12


def test_preview_colour_of_each_pixel_reads_back_as_its_depth_and_invalid_is_black(tmp_path):
    rng = np.random.default_rng(3)
    depth = np.exp(rng.uniform(np.log(0.6), np.log(60.0), (40, 50))).astype(np.float32)
    depth[5:9, 7:20] = np.nan
    depth[20, 3] = 0.0
    settings = PreviewSettings()
    write_png_rgb(tmp_path / "p.png", depth_preview(depth, (0.6, 60.0), settings))
    rgb = read_png_rgb(tmp_path / "p.png")  # through the PNG file: lossless
    assert rgb.shape == (40, 50, 3) and rgb.dtype == np.uint8
    back = depth_from_rgb(rgb, 0.6, 60.0)
    invalid = ~(np.isfinite(depth) & (depth > 0))
    assert np.array_equal(np.isnan(back), invalid)
    assert np.all(rgb[invalid] == 0)
    half_step = np.log(60.0 / 0.6) / 255 / 2
    assert np.max(np.abs(np.log(back[~invalid] / depth[~invalid]))) <= half_step + 1e-6
    # the invalid colour is far from every turbo colour: it cannot be mistaken for a depth
    assert np.min(np.linalg.norm(colormap_lut("turbo").astype(float), axis=1)) > 70


def test_depths_outside_the_range_get_the_end_colours():
    lut = colormap_lut("viridis")
    rgb = depth_preview(np.array([[0.1, 1000.0]]), (1.0, 10.0), PreviewSettings(colormap="viridis"))
    assert rgb[0, 0].tolist() == lut[255].tolist() and rgb[0, 1].tolist() == lut[0].tolist()


def test_run_range_covers_every_frames_bulk_and_percentiles_ignore_invalid():
    a = np.full((8, 8), 2.0)
    a[0, 0] = np.nan
    b = np.linspace(5.0, 50.0, 64).reshape(8, 8)
    ra, rb = depth_percentiles(a, (2, 98), step=1), depth_percentiles(b, (0, 100), step=1)
    assert ra == (2.0, 2.0) and rb == (5.0, 50.0)
    assert run_depth_range([ra, None, rb]) == (2.0, 50.0)
    assert run_depth_range([None]) is None
    lo, hi = run_depth_range([ra])
    assert lo < 2.0 < hi  # widened, a usable range
    assert depth_percentiles(np.full((4, 4), np.nan)) is None


def test_error_preview_sign_and_invalid():
    gt = np.full((2, 3), 10.0)
    gt[1, 2] = 0.0  # no ground truth
    depth = np.array([[8.0, 10.0, 12.0], [5.0, np.nan, 10.0]])
    s = PreviewSettings(error_range=0.2)
    rgb = error_preview(depth, gt, s)
    lut = colormap_lut("coolwarm")
    assert rgb[0, 0].tolist() == lut[0].tolist()  # -20 %: bluest
    assert rgb[0, 2].tolist() == lut[254].tolist() == [180, 4, 38]  # +20 %: reddest
    assert rgb[0, 1].tolist() == lut[127].tolist() == [221, 221, 221]  # 0 %: the grey centre
    assert rgb[1, 0].tolist() == lut[0].tolist()  # -50 % clipped
    assert rgb[1, 1].tolist() == [0, 0, 0] and rgb[1, 2].tolist() == [0, 0, 0]
    err = relative_error(depth, gt)
    assert err[0, 0] == pytest.approx(-0.2) and np.isnan(err[1, 2])


def test_settings_and_range_parsing_reject_bad_values():
    assert parse_depth_range("0.5:80") == (0.5, 80.0)
    for bad in ("80:0.5", "0:10", "a:b", "5"):
        with pytest.raises(SettingsError):
            parse_depth_range(bad)
    with pytest.raises(UnknownNameError, match="turbo"):
        PreviewSettings(colormap="jet")
    with pytest.raises(SettingsError):
        PreviewSettings(scale="sqrt")
    with pytest.raises(SettingsError):
        PreviewSettings(depth_range=(0.0, 5.0))
    with pytest.raises(SettingsError):
        depth_to_index(np.ones(2), 0.0, 1.0, "log")


def test_png_encoding_is_lossless_and_uses_a_palette_when_it_can(tmp_path):
    import cv2

    rng = np.random.default_rng(5)
    lut = colormap_lut("turbo")
    few = lut[rng.integers(0, 256, (30, 41))]  # <= 256 colours: palette PNG
    many = rng.integers(0, 256, (30, 41, 3), dtype=np.uint8)  # thousands of colours: RGB PNG
    for rgb in (few, many):
        data = encode_png_rgb(rgb)
        back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        assert np.array_equal(back, rgb)
    assert encode_png_rgb(few)[25] == 3 and encode_png_rgb(many)[25] == 2  # IHDR colour type
    # an error map with invalid pixels has at most 255 + 1 colours: still a palette PNG
    depth = rng.uniform(5, 15, (30, 41))
    depth[:3] = np.nan
    err = error_preview(depth, np.full((30, 41), 10.0), PreviewSettings(error_range=0.5))
    assert len(np.unique(err.reshape(-1, 3), axis=0)) > 200 and encode_png_rgb(err)[25] == 3
    with pytest.raises(InputError, match="beyond the palette"):
        encode_png_indexed(np.full((2, 2), 3, np.uint8), lut[:3])
