"""Mip-mapped photographic textures and vectorised anisotropic texture sampling.

Textures come from the photos bundled with scikit-image (``skimage.data``: brick, grass,
gravel, coffee, chelsea, rocket, astronaut, camera, ...; only images documented as CC0,
public domain or without known copyright restrictions) plus one procedural, seeded
fractal-noise texture ("clouds") used for large-scale brightness variation; nothing is
downloaded.
A texture is resized to a power-of-two size, optionally made seamlessly tileable
(offset-and-blend) and stored as a box-filtered mip pyramid packed into one
array, so that samples at different pyramid levels can be gathered in one numpy call.

Sampling (:func:`sample_texture`) is trilinear (bilinear in two levels) with up to
``max_aniso`` taps along the major axis of the pixel footprint (like GPU anisotropic
filtering), which keeps far and grazing surfaces (the road) free of aliasing, so that the
same features are found in consecutive frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, MissingDependencyError, UnknownNameError, lookup


@dataclass(frozen=True)
class MipTexture:
    """A packed mip pyramid.

    Attributes:
        name: texture name.
        data: (P, 3) uint8 RGB texels of all levels, level after level, row-major.
        widths, heights, offsets: (L,) int64 size and first texel index of each level.
        periodic: True: coordinates wrap (tiling); False: clamp to the edge (decals).
    """

    name: str
    data: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    offsets: np.ndarray
    periodic: bool

    @property
    def width(self) -> int:
        return int(self.widths[0])

    @property
    def height(self) -> int:
        return int(self.heights[0])

    @property
    def levels(self) -> int:
        return len(self.widths)


def _blend_with_roll(img: np.ndarray, axis: int) -> np.ndarray:
    n = img.shape[axis]
    a = np.sin(np.pi * (np.arange(n) + 0.5) / n) ** 2
    norm = 1.0 / np.sqrt(a * a + (1 - a) ** 2)
    shape = [1, 1, 1]
    shape[axis] = n
    a = a.reshape(shape).astype(np.float32)
    norm = norm.reshape(shape).astype(np.float32)
    mean = img.mean(axis=(0, 1), keepdims=True)
    mixed = a * (img - mean) + (1 - a) * (np.roll(img, n // 2, axis=axis) - mean)
    return mean + norm * mixed


def make_tileable(image) -> np.ndarray:
    """Seamlessly tileable version of ``image: (H, W, C)`` float (offset-and-blend).

    First along x: ``a(x) img + (1 - a(x)) roll_x(img, W/2)`` with ``a = sin^2(pi x / W)``
    (the rolled copy is continuous across the wrap, the original across the roll seam),
    then the same along y on the result (both terms stay periodic along x). Deviations
    from the mean are divided by ``sqrt(a^2 + (1 - a)^2)`` so that blending two
    uncorrelated copies does not wash out the contrast in the middle of the blend.
    """
    img = np.asarray(image, dtype=np.float32)
    return _blend_with_roll(_blend_with_roll(img, 1), 0)


def build_mip_texture(name: str, image, *, size: int = 512, tile: bool = True) -> MipTexture:
    """Mip pyramid of ``image: (H, W, 3)`` uint8 RGB (or (H, W) grey).

    The image is resized (INTER_AREA) to ``size`` x ``size`` texels (a power of two).
    With ``tile`` it is made seamlessly tileable (:func:`make_tileable`) and the texture
    is ``periodic``; without it coordinates clamp at the edges (decals, posters).
    Each level is the 2 x 2 box average of the previous one (computed in float32).
    """
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    image = check_image("image", image, channels=3)
    if size <= 0 or size & (size - 1):
        raise InputError(f"texture size must be a power of two, got {size}")
    img = cv2.resize(image.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
    if tile:
        img = make_tileable(img)
    levels = [img]
    while min(levels[-1].shape[:2]) > 1:
        a = levels[-1]
        levels.append(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]))
    packed = [np.clip(np.rint(lv), 0, 255).astype(np.uint8).reshape(-1, 3) for lv in levels]
    sizes = np.array([lv.shape[0] * lv.shape[1] for lv in levels], dtype=np.int64)
    return MipTexture(
        name=name,
        data=np.concatenate(packed, axis=0),
        widths=np.array([lv.shape[1] for lv in levels], dtype=np.int64),
        heights=np.array([lv.shape[0] for lv in levels], dtype=np.int64),
        offsets=np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
        periodic=tile,
    )


def _bilinear(tex: MipTexture, s: np.ndarray, t: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Bilinear sample at integer ``level: (N,)``; ``s, t: (N,)`` level-0 texel coordinates."""
    w = tex.widths[level]
    h = tex.heights[level]
    off = tex.offsets[level]
    scale = np.ldexp(1.0, -level)
    x = s * scale - 0.5
    y = t * scale - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    if tex.periodic:
        x0 = np.mod(x0, w)
        y0 = np.mod(y0, h)
        x1 = x0 + 1
        x1 = np.where(x1 == w, 0, x1)
        y1 = y0 + 1
        y1 = np.where(y1 == h, 0, y1)
    else:
        x1 = np.clip(x0 + 1, 0, w - 1)
        y1 = np.clip(y0 + 1, 0, h - 1)
        x0 = np.clip(x0, 0, w - 1)
        y0 = np.clip(y0, 0, h - 1)
    d = tex.data
    r0 = off + y0 * w
    r1 = off + y1 * w
    c00 = np.take(d, r0 + x0, axis=0).astype(np.float32)
    c01 = np.take(d, r0 + x1, axis=0).astype(np.float32)
    c10 = np.take(d, r1 + x0, axis=0).astype(np.float32)
    c11 = np.take(d, r1 + x1, axis=0).astype(np.float32)
    top = c00 + (c01 - c00) * fx
    bottom = c10 + (c11 - c10) * fx
    return top + (bottom - top) * fy


def sample_trilinear(tex: MipTexture, s, t, lod) -> np.ndarray:
    """Trilinear sample: ``s, t, lod: (N,)`` (level-0 texels, level of detail) -> (N, 3) float32 0..255."""
    s = check_array("s", s, (None,))
    t = check_array("t", t, (len(s),))
    lod = np.clip(check_array("lod", lod, (len(s),)), 0.0, tex.levels - 1)
    l0 = np.floor(lod).astype(np.int64)
    l1 = np.minimum(l0 + 1, tex.levels - 1)
    f = (lod - l0).astype(np.float32)[:, None]
    c0 = _bilinear(tex, s, t, l0)
    c1 = _bilinear(tex, s, t, l1)
    return c0 + (c1 - c0) * f


def sample_texture(tex: MipTexture, s, t, ds_dx, dt_dx, ds_dy, dt_dy, *, max_aniso: int = 8) -> np.ndarray:
    """Anisotropically filtered texture sample.

    Args:
        s, t: (N,) level-0 texel coordinates of the sample centres.
        ds_dx, dt_dx, ds_dy, dt_dy: (N,) texel derivatives per output-sample step in x / y.
        max_aniso: most taps along the footprint's major axis (a power of two).

    Returns:
        (N, 3) float32 RGB in 0..255.
    """
    s = check_array("s", s, (None,))
    n = len(s)
    t, ds_dx, dt_dx, ds_dy, dt_dy = (check_array(k, v, (n,)) for k, v in
                                     (("t", t), ("ds_dx", ds_dx), ("dt_dx", dt_dx), ("ds_dy", ds_dy), ("dt_dy", dt_dy)))
    lx = np.hypot(ds_dx, dt_dx)
    ly = np.hypot(ds_dy, dt_dy)
    x_major = lx >= ly
    p_max = np.where(x_major, lx, ly)
    p_min = np.maximum(np.where(x_major, ly, lx), 1e-12)
    ratio = np.minimum(p_max / p_min, float(max_aniso))
    taps = np.where(ratio > 1.0, 2 ** np.ceil(np.log2(np.maximum(ratio, 1.0))), 1.0)
    taps = np.minimum(taps, max_aniso).astype(np.int64)
    lod = np.log2(np.maximum(p_max / taps, 1e-12))
    ms = np.where(x_major, ds_dx, ds_dy)
    mt = np.where(x_major, dt_dx, dt_dy)
    out = np.empty((n, 3), dtype=np.float32)
    for k in np.unique(taps):
        sel = np.flatnonzero(taps == k)
        acc = np.zeros((len(sel), 3), dtype=np.float32)
        for i in range(int(k)):
            o = (i + 0.5) / k - 0.5
            acc += sample_trilinear(tex, s[sel] + o * ms[sel], t[sel] + o * mt[sel], lod[sel])
        out[sel] = acc / np.float32(k)
    return out


# --------------------------------------------------------------------------- photos
#: name -> (skimage.data function, tileable material?) of the photos used by the bundled scenes;
#: only images that scikit-image documents as CC0, public domain or "no known copyright
#: restrictions" are used.
_PHOTOS = {
    "astronaut": ("astronaut", False),
    "brick": ("brick", True),
    "camera": ("camera", False),
    "cat": ("cat", False),
    "cell": ("cell", False),
    "chelsea": ("chelsea", False),
    "clock": ("clock", False),
    "coffee": ("coffee", False),
    "coins": ("coins", True),
    "grass": ("grass", True),
    "gravel": ("gravel", True),
    "hubble": ("hubble_deep_field", False),
    "ihc": ("immunohistochemistry", False),
    "retina": ("retina", False),
    "rocket": ("rocket", False),
    "text": ("text", False),
}
#: procedural (generated, seeded) tileable textures: name -> seed of :func:`fractal_noise`
_PROCEDURAL = {"clouds": 7}


def fractal_noise(size: int = 512, seed: int = 0, octaves: int = 6, persistence: float = 0.55) -> np.ndarray:
    """Seamlessly tileable value noise ``(size, size, 3)`` uint8 (grey), deterministic per seed.

    Octave k is a ``(4 * 2^k)``-cell periodic grid of uniform random values, upsampled with
    smoothstep-weighted bilinear interpolation and weighted ``persistence^k``.
    """
    rng = np.random.default_rng(seed)
    pos = (np.arange(size) + 0.5) / size
    acc = np.zeros((size, size))
    for k in range(octaves):
        n = 4 * 2 ** k
        grid = rng.random((n, n))
        x = pos * n - 0.5
        i0 = np.floor(x).astype(np.int64)
        f = x - i0
        f = f * f * (3 - 2 * f)
        i0 = np.mod(i0, n)
        i1 = np.mod(i0 + 1, n)
        rows = grid[i0] * (1 - f)[:, None] + grid[i1] * f[:, None]
        acc += persistence ** k * (rows[:, i0] * (1 - f)[None] + rows[:, i1] * f[None])
    acc = (acc - acc.min()) / max(acc.max() - acc.min(), 1e-12)
    return np.repeat(np.rint(acc * 255).astype(np.uint8)[:, :, None], 3, axis=2)


def photo_names() -> list[str]:
    """Names accepted by :func:`load_photo` (skimage photos and procedural textures)."""
    return sorted(set(_PHOTOS) | set(_PROCEDURAL))


def load_photo(name: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB texture ``name``: a photo from ``skimage.data`` (bundled with
    scikit-image, no download) or a procedural texture.

    Raises:
        UnknownNameError: unknown name. MissingDependencyError: scikit-image is absent.
    """
    if name in _PROCEDURAL:
        return fractal_noise(seed=_PROCEDURAL[name])
    if name not in _PHOTOS:
        raise UnknownNameError("texture photo", name, photo_names())
    try:
        import skimage.data
    except ImportError:
        raise MissingDependencyError("scikit-image", "dev", "rendering sample sequences") from None
    img = np.asarray(getattr(skimage.data, _PHOTOS[name][0])())
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3])


def photo_tiles(name: str) -> bool:
    """Whether texture ``name`` is a tileable material (periodic) rather than a decal (clamped)."""
    if name in _PROCEDURAL:
        return True
    return lookup("texture photo", name, _PHOTOS)[1]
