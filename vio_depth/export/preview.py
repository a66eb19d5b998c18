"""Colourised previews: depth maps and signed error maps against ground truth, as RGB PNGs.

Depth previews use a sequential perceptual colormap (default turbo) on a log-depth axis,
near = warm, far = cool, over a fixed range or one range for the whole run
(:func:`run_depth_range`), so colours mean the same depth in every frame of a run.
Invalid pixels (NaN, <= 0) get ``invalid_rgb`` (default black, a colour no sequential
map here uses: turbo's darkest entry is 78 RGB units away).

Error previews show the signed relative error ``(depth - gt) / gt`` on a diverging map
(blue = too near, grey = right, red = too far) over ``[-error_range, +error_range]``;
pixels without a valid depth or ground truth are ``invalid_rgb``.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import cv2
import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, SettingsError, UnknownNameError

from ..io.depth_png import write_bytes_atomic
from ..io.images import read_rgb_image
from .colormap import ERROR_LEVELS, SCALES, available_colormaps, colormap_lut, colourise, depth_to_index

ERROR_COLORMAP = "coolwarm"


@dataclass(frozen=True)
class PreviewSettings:
    """How depth and error previews look.

    Attributes:
        colormap: sequential colormap name (:func:`~vio_depth.export.colormap.available_colormaps`).
        scale: "log" (default: equal colour steps per depth ratio, suits 2-200 m streets and
            0.5-7 m rooms alike) or "linear".
        depth_range: fixed ``(vmin, vmax)`` metres, or None for one range per run from the
            depth maps' percentiles (:func:`run_depth_range`).
        percentiles: low/high percentiles of each frame's valid depth used for the run range;
            95 (not 98-99) because sky with near-zero disparity gets depths of hundreds of
            metres or more (5 % of the street sample's pixels), which would squeeze the scene
            into a few colours; such pixels get the far-end colour.
        invalid_rgb: colour of invalid pixels.
        error_range: relative error at the ends of the error colormap (0.2 = +-20 %).
    """

    colormap: str = "turbo"
    scale: str = "log"
    depth_range: tuple[float, float] | None = None
    percentiles: tuple[float, float] = (2.0, 95.0)
    invalid_rgb: tuple[int, int, int] = (0, 0, 0)
    error_range: float = 0.2

    def __post_init__(self):
        if self.colormap not in available_colormaps():
            raise UnknownNameError("colormap", self.colormap, available_colormaps())
        if self.scale not in SCALES:
            raise SettingsError(f"preview scale must be one of {', '.join(SCALES)}, got {self.scale!r}")
        if self.depth_range is not None:
            lo, hi = self.depth_range
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
                raise SettingsError(f"preview depth range must satisfy 0 < min < max metres, got {self.depth_range}")
        lo, hi = self.percentiles
        if not 0 <= lo < hi <= 100:
            raise SettingsError(f"preview percentiles must satisfy 0 <= low < high <= 100, got {self.percentiles}")
        if len(self.invalid_rgb) != 3 or not all(0 <= int(c) <= 255 for c in self.invalid_rgb):
            raise SettingsError(f"invalid_rgb must be three values in 0..255, got {self.invalid_rgb}")
        if not (np.isfinite(self.error_range) and self.error_range > 0):
            raise SettingsError(f"error_range must be > 0, got {self.error_range}")


def parse_depth_range(text: str) -> tuple[float, float]:
    """``"MIN:MAX"`` metres (e.g. ``"0.5:80"``) -> ``(0.5, 80.0)``.

    Raises:
        SettingsError: not two numbers with ``0 < MIN < MAX``.
    """
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise SettingsError(f"preview range must be MIN:MAX in metres (e.g. 0.5:80), got {text!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise SettingsError(f"preview range must satisfy 0 < MIN < MAX metres, got {text!r}")
    return lo, hi


def depth_percentiles(depth, percentiles=(2.0, 95.0), step: int = 4) -> tuple[float, float] | None:
    """Low/high percentiles (metres) of the valid pixels of ``depth: (H, W)`` metres.

    Every ``step``-th pixel in each direction is used (enough for a colour range).
    Returns None when no pixel is valid.
    """
    depth = check_array("depth", depth, (None, None))
    sub = depth[::step, ::step]
    with np.errstate(invalid="ignore"):
        values = sub[np.isfinite(sub) & (sub > 0)]
    if values.size == 0:
        return None
    lo, hi = np.percentile(values, percentiles)
    return float(lo), float(hi)


def run_depth_range(frame_ranges) -> tuple[float, float] | None:
    """One colour range (metres) for a run from per-frame ``(low, high)`` percentiles.

    The lowest low and the highest high, so no frame's bulk is clipped. None without
    any frame range. A degenerate range (one depth everywhere) is widened by 1 %.
    """
    ranges = [r for r in frame_ranges if r is not None]
    if not ranges:
        return None
    lo = min(r[0] for r in ranges)
    hi = max(r[1] for r in ranges)
    if not hi > lo:
        lo, hi = lo / 1.01, hi * 1.01
    return lo, hi


def depth_preview(depth, depth_range: tuple[float, float], settings: PreviewSettings = PreviewSettings()) -> np.ndarray:
    """Colourise ``depth: (H, W)`` metres (NaN / <= 0 invalid) -> ``(H, W, 3)`` uint8 RGB.

    ``depth_range``: ``(vmin, vmax)`` metres; depths outside it get the end colours.
    """
    depth = check_array("depth", depth, (None, None))
    index, valid = depth_to_index(depth, depth_range[0], depth_range[1], settings.scale)
    return colourise(index, valid, colormap_lut(settings.colormap), settings.invalid_rgb)


def relative_error(depth, gt_depth) -> np.ndarray:
    """Signed relative error ``(depth - gt) / gt`` of ``depth, gt_depth: (H, W)`` metres.

    NaN where either map is invalid (NaN, inf or <= 0).
    """
    depth = check_array("depth", depth, (None, None))
    gt = check_array("gt_depth", gt_depth, depth.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(depth) & (depth > 0) & np.isfinite(gt) & (gt > 0)
        return np.where(ok, (depth - gt) / np.where(ok, gt, 1.0), np.nan)


def error_preview(depth, gt_depth, settings: PreviewSettings = PreviewSettings()) -> np.ndarray:
    """Colourise the signed relative error of ``depth`` against ``gt_depth`` (both (H, W) metres).

    Returns ``(H, W, 3)`` uint8 RGB: coolwarm over ``[-error_range, +error_range]`` in
    :data:`~vio_depth.export.colormap.ERROR_LEVELS` steps (index 0 = ``-error_range``, blue,
    depth too small; 127 = exact, grey; 254 = ``+error_range``, red, too large), clipped;
    pixels without both depths are ``invalid_rgb``.
    """
    err = relative_error(depth, gt_depth)
    valid = np.isfinite(err)
    r = settings.error_range
    t = (np.clip(np.where(valid, err, 0.0), -r, r) + r) / (2 * r)
    index = np.rint(t * (ERROR_LEVELS - 1)).astype(np.uint8)
    return colourise(index, valid, colormap_lut(ERROR_COLORMAP), settings.invalid_rgb)


def encode_png_rgb(rgb) -> bytes:
    """Lossless PNG bytes of an ``(H, W, 3)`` uint8 RGB image.

    Colour-coded maps use at most a LUT's 256 colours (plus the invalid colour): when the
    image has <= 256 distinct colours it is stored as an 8-bit palette PNG
    (:func:`encode_png_indexed`, a third of the size of RGB for noisy depth), else as RGB.
    """
    rgb = check_image("rgb", rgb, channels=3)
    if rgb.dtype != np.uint8:
        raise InputError(f"rgb: expected uint8, got {rgb.dtype}")
    key = (rgb[..., 0].astype(np.uint32) << 16) | (rgb[..., 1].astype(np.uint32) << 8) | rgb[..., 2]
    colours, index = np.unique(key.ravel(), return_inverse=True)
    if len(colours) <= 256:
        palette = np.stack([(colours >> 16) & 255, (colours >> 8) & 255, colours & 255], axis=1).astype(np.uint8)
        return encode_png_indexed(index.reshape(key.shape).astype(np.uint8), palette)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover - cv2 failure
        raise InputError("cannot encode PNG")
    return buf.tobytes()


def encode_png_indexed(index, palette) -> bytes:
    """8-bit palette PNG bytes: ``index: (H, W)`` uint8 into ``palette: (K, 3)`` uint8 RGB, K <= 256."""
    index = check_image("index", index)
    palette = check_array("palette", palette, (None, 3), dtype=None)
    if index.dtype != np.uint8 or palette.dtype != np.uint8 or not 1 <= len(palette) <= 256:
        raise InputError("indexed PNG: uint8 index and a uint8 palette of 1..256 colours expected")
    if int(index.max(initial=0)) >= len(palette):
        raise InputError("indexed PNG: index beyond the palette")
    h, w = index.shape

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    rows = np.concatenate([np.zeros((h, 1), np.uint8), index], axis=1)  # filter type 0 per row
    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0))
            + chunk(b"PLTE", palette.tobytes())
            + chunk(b"IDAT", zlib.compress(rows.tobytes(), 9))
            + chunk(b"IEND", b""))


def encode_jpeg_rgb(rgb, quality: int = 90) -> bytes:
    """JPEG bytes of an ``(H, W, 3)`` uint8 RGB image (lossy: for thumbnails, never for data)."""
    rgb = check_image("rgb", rgb, channels=3)
    if rgb.dtype != np.uint8:
        raise InputError(f"rgb: expected uint8, got {rgb.dtype}")
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - cv2 failure
        raise InputError("cannot encode JPEG")
    return buf.tobytes()


def write_png_rgb(path, rgb) -> None:
    """Write an ``(H, W, 3)`` uint8 RGB image as PNG (lossless), atomically (temporary name + rename)."""
    try:
        write_bytes_atomic(path, encode_png_rgb(rgb))
    except OSError as exc:
        raise InputError(f"{path}: cannot write PNG ({exc.strerror})") from None


def write_jpeg_rgb(path, rgb, quality: int = 90) -> None:
    """Write an ``(H, W, 3)`` uint8 RGB image as JPEG, atomically (thumbnails: about 8x smaller
    than PNG for the noisy colours of depth and error maps)."""
    try:
        write_bytes_atomic(path, encode_jpeg_rgb(rgb, quality))
    except OSError as exc:
        raise InputError(f"{path}: cannot write JPEG ({exc.strerror})") from None


def read_png_rgb(path) -> np.ndarray:
    """Read a PNG/JPEG as ``(H, W, 3)`` uint8 RGB.

    The bytes are read by Python (any path works), decoded by OpenCV.

    Raises:
        InputError: missing or undecodable file.
    """
    return read_rgb_image(path)
