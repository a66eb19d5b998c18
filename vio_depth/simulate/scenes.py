"""Textured planar scenes for the sample-sequence renderer.

A :class:`Scene` is a set of textured rectangles (quads) in a world frame with z up,
metres. Boxes (buildings, cars, furniture) are five or six quads; decals (windows,
posters, lane markings) are quads a few millimetres in front of a surface. Scenes are
built by :class:`SceneBuilder` from a seeded random generator, so a scene is a pure
function of its builder arguments.

The built-in scenes are in :mod:`vio_depth.simulate.scene_library`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError

from .textures import MipTexture, build_mip_texture, load_photo, photo_tiles


@dataclass(frozen=True)
class Material:
    """How a quad is coloured.

    Attributes:
        texture: photo name (see :func:`vio_depth.simulate.textures.photo_names`).
        tile_m: metres covered by one texture width (tiling materials) by default.
        tint: RGB multipliers applied to the texture (0..1 each, may exceed 1 slightly).
        contrast: texture contrast around its mean colour (1 = unchanged).
        macro: optional photo modulating brightness at a large scale (breaks repetition).
        macro_tile_m: metres covered by one macro texture width.
        macro_strength: relative brightness modulation amplitude of the macro texture.
    """

    texture: str
    tile_m: float = 2.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    contrast: float = 1.0
    macro: str | None = None
    macro_tile_m: float = 25.0
    macro_strength: float = 0.0


@dataclass
class Scene:
    """Quads in world coordinates (z up, metres) and what they look like.

    Attributes (Q quads):
        origin: (Q, 3) corner of each quad where its texture coordinates are (0, 0).
        axis_u, axis_v: (Q, 3) orthonormal in-plane unit axes (v points "down" the texture).
        size: (Q, 2) metres along u and v.
        normal: (Q, 3) unit normal ``axis_v x axis_u``; one-sided quads are seen from this side
            (seen from it, u runs right and v down, like image axes).
        two_sided: (Q,) bool.
        material: (Q,) int index into ``materials``.
        texel_scale: (Q, 2) level-0 texels per metre along u and v.
        texel_offset: (Q, 2) texel coordinates at ``origin``.
        shade: (Q,) float brightness factor (ambient + diffuse lighting).
        materials: list of :class:`Material`.
        textures: photo name -> :class:`MipTexture`.
        sky: True: rays that hit nothing get a sky gradient (depth invalid); False: black.
        fog_m: distance (m) of the exponential haze, or 0 for none.
    """

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size: np.ndarray
    normal: np.ndarray
    two_sided: np.ndarray
    material: np.ndarray
    texel_scale: np.ndarray
    texel_offset: np.ndarray
    shade: np.ndarray
    materials: list
    textures: dict
    sky: bool = False
    fog_m: float = 0.0
    name: str = ""

    def __len__(self) -> int:
        return len(self.origin)

    def corners(self) -> np.ndarray:
        """(Q, 4, 3) world corners: origin, +u, +u+v, +v."""
        U = self.axis_u * self.size[:, :1]
        V = self.axis_v * self.size[:, 1:]
        o = self.origin
        return np.stack([o, o + U, o + U + V, o + V], axis=1)


_TEXTURE_CACHE: dict[tuple[str, int], MipTexture] = {}


def get_texture(name: str, size: int = 512) -> MipTexture:
    """Mip texture of photo ``name`` (cached per process)."""
    key = (name, size)
    if key not in _TEXTURE_CACHE:
        _TEXTURE_CACHE[key] = build_mip_texture(name, load_photo(name), size=size, tile=photo_tiles(name))
    return _TEXTURE_CACHE[key]


@dataclass
class SceneBuilder:
    """Accumulates quads; :meth:`build` returns the :class:`Scene`.

    Args:
        seed: seeds the random texture offsets (and the scene generators that use ``rng``).
        light_dir: (3,) direction towards the light, world frame.
        ambient, diffuse: shade = ambient + diffuse * max(0, normal . light_dir).
        texture_size: base texture size in texels (power of two).
    """

    seed: int = 0
    light_dir: tuple[float, float, float] = (0.35, -0.5, 0.8)
    ambient: float = 0.6
    diffuse: float = 0.45
    texture_size: int = 512
    _quads: list = field(default_factory=list, init=False, repr=False)
    _materials: list = field(default_factory=list, init=False, repr=False)
    _material_index: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self):
        self.rng = np.random.default_rng(self.seed)

    def material(self, mat: Material) -> int:
        """Index of ``mat`` (registered once)."""
        if mat not in self._material_index:
            self._material_index[mat] = len(self._materials)
            self._materials.append(mat)
        return self._material_index[mat]

    def quad(self, origin, u_vec, v_vec, mat: Material, *, fit: bool = False, two_sided: bool = False,
             offset: tuple[float, float] | None = None) -> None:
        """Add the rectangle ``origin + [0, 1] u_vec + [0, 1] v_vec`` (metres, world frame).

        ``u_vec`` and ``v_vec`` (each (3,)) must be orthogonal. The visible side is the
        one ``v_vec x u_vec`` points to: seen from it, u runs right and v down (image axes). ``fit``: the texture covers the quad exactly once (posters);
        otherwise it tiles every ``mat.tile_m`` metres with a random offset (or ``offset``,
        in texels).
        """
        o = check_array("origin", origin, (3,), finite=True)
        u = check_array("u_vec", u_vec, (3,), finite=True)
        v = check_array("v_vec", v_vec, (3,), finite=True)
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if lu <= 0 or lv <= 0 or abs(float(u @ v)) > 1e-9 * lu * lv:
            raise InputError("quad edges must be non-zero and orthogonal")
        tex_size = self.texture_size
        if fit:
            scale = (tex_size / lu, tex_size / lv)
            off = (0.0, 0.0)
        else:
            scale = (tex_size / mat.tile_m, tex_size / mat.tile_m)
            if offset is not None:
                off = offset
            elif photo_tiles(mat.texture):
                off = tuple(self.rng.uniform(0, tex_size, 2))
            else:  # a random crop that stays inside a non-tiling texture
                span = np.maximum(tex_size - np.array([lu, lv]) * scale[0], 0.0)
                off = tuple(self.rng.uniform(0, 1, 2) * span)
        self._quads.append((o, u / lu, v / lv, (lu, lv), two_sided, self.material(mat), scale, off))

    def box(self, lo, hi, mats, *, skip=("bottom",), fit_faces: tuple = ()) -> None:
        """Axis-aligned box from ``lo: (3,)`` to ``hi: (3,)`` metres with outward faces.

        ``mats``: one :class:`Material` or a dict face -> Material with faces
        "+x", "-x", "+y", "-y", "top", "bottom"; faces in ``skip`` are omitted. Texture
        v runs downwards on the side faces.
        """
        lo = check_array("lo", lo, (3,), finite=True)
        hi = check_array("hi", hi, (3,), finite=True)
        if np.any(hi <= lo):
            raise InputError(f"box: hi {hi} must exceed lo {lo}")
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        dx, dy, dz = hi - lo
        faces = {
            "+x": ((x1, y0, z1), (0, dy, 0), (0, 0, -dz)),
            "-x": ((x0, y1, z1), (0, -dy, 0), (0, 0, -dz)),
            "+y": ((x1, y1, z1), (-dx, 0, 0), (0, 0, -dz)),
            "-y": ((x0, y0, z1), (dx, 0, 0), (0, 0, -dz)),
            "top": ((x0, y1, z1), (dx, 0, 0), (0, -dy, 0)),
            "bottom": ((x0, y0, z0), (dx, 0, 0), (0, dy, 0)),
        }
        for name, (o, u, v) in faces.items():
            if name in skip:
                continue
            mat = mats[name] if isinstance(mats, dict) else mats
            self.quad(np.array(o, float), np.array(u, float), np.array(v, float), mat, fit=name in fit_faces)

    def decal(self, center, u_dir, v_dir, width: float, height: float, mat: Material, *,
              lift: float = 0.01, fit: bool = True) -> None:
        """A ``width`` x ``height`` m rectangle centred on ``center: (3,)`` in the plane spanned
        by unit ``u_dir`` (texture right) and ``v_dir`` (texture down), lifted ``lift`` m
        along its visible normal ``v_dir x u_dir``."""
        c = check_array("center", center, (3,), finite=True)
        u = check_array("u_dir", u_dir, (3,), finite=True)
        v = check_array("v_dir", v_dir, (3,), finite=True)
        u = u / np.linalg.norm(u)
        v = v / np.linalg.norm(v)
        n = np.cross(v, u)
        o = c - 0.5 * width * u - 0.5 * height * v + lift * n
        self.quad(o, width * u, height * v, mat, fit=fit)

    def horizontal(self, x0: float, y0: float, x1: float, y1: float, z: float, mat: Material, *,
                   up: bool = True) -> None:
        """Axis-aligned horizontal rectangle [x0, x1] x [y0, y1] at height ``z`` metres,
        visible from above (``up``) or from below."""
        if up:
            self.quad((x0, y1, z), (x1 - x0, 0, 0), (0, y0 - y1, 0), mat)
        else:
            self.quad((x0, y0, z), (x1 - x0, 0, 0), (0, y1 - y0, 0), mat)

    def wall(self, left_xy, right_xy, z0: float, z1: float, mat: Material) -> None:
        """Vertical rectangle from ``z0`` to ``z1`` m whose visible side sees ``left_xy``
        on its left and ``right_xy: (2,)`` on its right."""
        (xl, yl), (xr, yr) = left_xy, right_xy
        self.quad((xl, yl, z1), (xr - xl, yr - yl, 0), (0, 0, z0 - z1), mat)

    def build(self, *, sky: bool = False, fog_m: float = 0.0, name: str = "") -> Scene:
        if not self._quads:
            raise InputError("scene has no quads")
        cols = list(zip(*self._quads))
        origin = np.array(cols[0], dtype=np.float64)
        axis_u = np.array(cols[1], dtype=np.float64)
        axis_v = np.array(cols[2], dtype=np.float64)
        normal = np.cross(axis_v, axis_u)
        light = np.asarray(self.light_dir, dtype=np.float64)
        light = light / np.linalg.norm(light)
        two_sided = np.array(cols[4], dtype=bool)
        lambert = normal @ light
        lambert = np.where(two_sided, np.abs(lambert), np.maximum(lambert, 0.0))
        textures = {}
        for mat in self._materials:
            for tex_name in (mat.texture, mat.macro):
                if tex_name is not None and tex_name not in textures:
                    textures[tex_name] = get_texture(tex_name, self.texture_size)
        return Scene(
            origin=origin, axis_u=axis_u, axis_v=axis_v,
            size=np.array(cols[3], dtype=np.float64),
            normal=normal, two_sided=two_sided,
            material=np.array(cols[5], dtype=np.int64),
            texel_scale=np.array(cols[6], dtype=np.float64),
            texel_offset=np.array(cols[7], dtype=np.float64),
            shade=self.ambient + self.diffuse * lambert,
            materials=list(self._materials), textures=textures, sky=sky, fog_m=fog_m, name=name,
        )


# --------------------------------------------------------------------------- materials
