"""Vectorised numpy ray casting of textured planar scenes: RGB image + exact z-depth.

For a pinhole camera every pixel ray is ``r = ((u - cx) / fx, (v - cy) / fy, 1)`` in the
camera frame (x right, y down, z forward). A quad with camera-frame normal ``n`` through
the point ``o`` is hit at depth ``z = (n . o) / (n . r)``, the point ``X = z r``; its local
coordinates ``a = (X - o) . u``, ``b = (X - o) . v`` decide whether the ray is inside it.
The nearest hit wins (a z-buffer). Each quad is only tested against the rays inside the
bounding box of its projection (clipped against the near plane).

* **Depth**: one ray through each pixel centre (pixel (u, v) has its centre at integer
  coordinates, the OpenCV convention); ``depth[v, u]`` is the exact z of the nearest
  surface, 0 where the ray hits nothing (sky).
* **Colour**: ``supersampling`` x ``supersampling`` rays per pixel, each shaded with an
  anisotropically filtered texture lookup whose footprint comes from the analytic
  derivatives of (a, b) with respect to the sub-pixel position, averaged per pixel;
  then a constant per-face brightness (Lambert + ambient), exponential haze, and optional
  Gaussian sensor noise (seeded) before rounding to uint8.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, SettingsError

from .scenes import Scene
from .textures import sample_texture, sample_trilinear


@dataclass(frozen=True)
class RenderSettings:
    """Renderer settings.

    Attributes:
        supersampling: colour rays per pixel along each axis (2 = 4 rays per pixel).
        max_aniso: most texture taps along a footprint's major axis (power of two).
        near_m: rays ignore surfaces nearer than this (metres).
        noise_dn: standard deviation of the Gaussian sensor noise in 8-bit levels (0 = none).
        sky_horizon, sky_zenith: RGB (0..1) of the sky gradient (scenes with a sky).
    """

    supersampling: int = 2
    max_aniso: int = 8
    near_m: float = 0.05
    noise_dn: float = 1.0
    sky_horizon: tuple[float, float, float] = (0.82, 0.87, 0.93)
    sky_zenith: tuple[float, float, float] = (0.36, 0.55, 0.86)

    def __post_init__(self):
        if int(self.supersampling) != self.supersampling or self.supersampling < 1:
            raise SettingsError(f"supersampling must be a positive integer, got {self.supersampling}")
        if self.max_aniso < 1 or self.max_aniso & (self.max_aniso - 1):
            raise SettingsError(f"max_aniso must be a power of two, got {self.max_aniso}")
        if not self.near_m > 0 or not self.noise_dn >= 0:
            raise SettingsError("near_m must be > 0 and noise_dn >= 0")


@dataclass(frozen=True)
class RenderedView:
    """One rendered frame.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        depth: (H, W) float32 metres, exact z-depth at the pixel centres, 0 = no surface (sky).
    """

    image: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True)
class _CameraQuads:
    """Scene quads in the camera frame (all (Q, 3) or (Q,))."""

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray
    plane_d: np.ndarray   # n . o
    o_dot_u: np.ndarray
    o_dot_v: np.ndarray
    candidates: np.ndarray  # indices of quads facing the camera with some part in front
    corners: np.ndarray     # (Q, 4, 3)


def _to_camera(scene: Scene, T_w_c: np.ndarray, near: float) -> _CameraQuads:
    R_w_c = T_w_c[:3, :3]
    c = T_w_c[:3, 3]
    # p_c = R_w_c^T (p_w - c), written for row vectors as (p_w - c) @ R_w_c
    origin = (scene.origin - c) @ R_w_c
    axis_u = scene.axis_u @ R_w_c
    axis_v = scene.axis_v @ R_w_c
    normal = scene.normal @ R_w_c
    corners = (scene.corners() - c) @ R_w_c
    facing = scene.two_sided | (np.einsum("qi,qi->q", c - scene.origin, scene.normal) > 0)
    in_front = corners[:, :, 2].max(axis=1) > near
    return _CameraQuads(
        origin=origin, axis_u=axis_u, axis_v=axis_v, normal=normal,
        plane_d=np.einsum("qi,qi->q", normal, origin),
        o_dot_u=np.einsum("qi,qi->q", origin, axis_u),
        o_dot_v=np.einsum("qi,qi->q", origin, axis_v),
        candidates=np.flatnonzero(facing & in_front), corners=corners,
    )


def _clip_near(poly: np.ndarray, near: float) -> np.ndarray:
    """Clip the convex polygon ``poly: (K, 3)`` (camera frame) to z >= near."""
    out = []
    k = len(poly)
    for i in range(k):
        p, q = poly[i], poly[(i + 1) % k]
        pin, qin = p[2] >= near, q[2] >= near
        if pin:
            out.append(p)
        if pin != qin:
            s = (near - p[2]) / (q[2] - p[2])
            out.append(p + s * (q - p))
    return np.array(out).reshape(-1, 3)


def _pixel_bboxes(cq: _CameraQuads, camera: Camera, ss: int, near: float) -> np.ndarray:
    """(C, 4) int [row0, row1, col0, col1) grid index boxes of the candidate quads (empty when off-screen)."""
    idx = cq.candidates
    corners = cq.corners[idx]
    boxes = np.zeros((len(idx), 4), dtype=np.int64)
    all_front = corners[:, :, 2].min(axis=1) >= near
    uv_min = np.full((len(idx), 2), np.inf)
    uv_max = np.full((len(idx), 2), -np.inf)
    if all_front.any():
        cf = corners[all_front]
        u = camera.fx * cf[:, :, 0] / cf[:, :, 2] + camera.cx
        v = camera.fy * cf[:, :, 1] / cf[:, :, 2] + camera.cy
        uv_min[all_front] = np.stack([u.min(1), v.min(1)], 1)
        uv_max[all_front] = np.stack([u.max(1), v.max(1)], 1)
    for k in np.flatnonzero(~all_front):
        poly = _clip_near(corners[k], near)
        if len(poly) == 0:
            continue
        u = camera.fx * poly[:, 0] / poly[:, 2] + camera.cx
        v = camera.fy * poly[:, 1] / poly[:, 2] + camera.cy
        uv_min[k] = (u.min(), v.min())
        uv_max[k] = (u.max(), v.max())
    hs, ws = camera.height * ss, camera.width * ss
    finite = np.isfinite(uv_min).all(1)
    with np.errstate(invalid="ignore"):
        # grid index j <-> pixel coordinate u = (j + 0.5) / ss - 0.5
        c0 = np.floor((uv_min[:, 0] + 0.5) * ss - 0.5) - 1
        c1 = np.ceil((uv_max[:, 0] + 0.5) * ss - 0.5) + 2
        r0 = np.floor((uv_min[:, 1] + 0.5) * ss - 0.5) - 1
        r1 = np.ceil((uv_max[:, 1] + 0.5) * ss - 0.5) + 2
    boxes[finite, 0] = np.clip(r0[finite], 0, hs)
    boxes[finite, 1] = np.clip(r1[finite], 0, hs)
    boxes[finite, 2] = np.clip(c0[finite], 0, ws)
    boxes[finite, 3] = np.clip(c1[finite], 0, ws)
    return boxes


def _ray_grid(camera: Camera, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised ray coordinates ``rx: (W*ss,)`` and ``ry: (H*ss,)`` of the sub-pixel grid."""
    ju = (np.arange(camera.width * ss) + 0.5) / ss - 0.5
    iv = (np.arange(camera.height * ss) + 0.5) / ss - 0.5
    return (ju - camera.cx) / camera.fx, (iv - camera.cy) / camera.fy


def _visibility(scene: Scene, cq: _CameraQuads, camera: Camera, ss: int, near: float):
    """Z-buffer ``(H*ss, W*ss)`` float64 metres (inf = miss) and quad ids (-1 = miss)."""
    rx, ry = _ray_grid(camera, ss)
    hs, ws = len(ry), len(rx)
    zbuf = np.full((hs, ws), np.inf)
    qid = np.full((hs, ws), -1, dtype=np.int64)
    boxes = _pixel_bboxes(cq, camera, ss, near)
    for q, (r0, r1, c0, c1) in zip(cq.candidates, boxes):
        if r1 <= r0 or c1 <= c0:
            continue
        x = rx[None, c0:c1]
        y = ry[r0:r1, None]
        n, eu, ev = cq.normal[q], cq.axis_u[q], cq.axis_v[q]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = cq.plane_d[q] / (n[0] * x + n[1] * y + n[2])
        zsub = zbuf[r0:r1, c0:c1]
        m = (z > near) & (z < zsub)
        if not m.any():
            continue
        a = z * (eu[0] * x + eu[1] * y + eu[2]) - cq.o_dot_u[q]
        b = z * (ev[0] * x + ev[1] * y + ev[2]) - cq.o_dot_v[q]
        su, sv = scene.size[q]
        m &= (a >= 0) & (a <= su) & (b >= 0) & (b <= sv)
        zsub[m] = z[m]
        qid[r0:r1, c0:c1][m] = q
    return zbuf, qid


def render_depth(scene: Scene, camera: Camera, T_w_c, *, near_m: float = 0.05) -> np.ndarray:
    """Exact z-depth ``(H, W)`` float64 metres at the pixel centres (0 = nothing hit).

    ``T_w_c``: (4, 4) camera-to-world pose, metres. The camera must be undistorted.
    """
    T_w_c = check_transform("T_w_c", T_w_c)
    if camera.is_distorted:
        raise InputError("the renderer supports undistorted cameras only")
    cq = _to_camera(scene, T_w_c, near_m)
    zbuf, _ = _visibility(scene, cq, camera, 1, near_m)
    return np.where(np.isfinite(zbuf), zbuf, 0.0)


def _shade(scene: Scene, cq: _CameraQuads, camera: Camera, T_w_c: np.ndarray, ss: int, zbuf: np.ndarray,
           qid: np.ndarray, settings: RenderSettings) -> np.ndarray:
    """(H*ss, W*ss, 3) float32 linear colour 0..1 of the sub-pixel grid."""
    rx_all, ry_all = _ray_grid(camera, ss)
    hs, ws = zbuf.shape
    out = np.zeros((hs, ws, 3), dtype=np.float32)
    ii, jj = np.nonzero(qid >= 0)
    if len(ii):
        q = qid[ii, jj]
        z = zbuf[ii, jj]
        rx = rx_all[jj]
        ry = ry_all[ii]
        eu = cq.axis_u[q]
        ev = cq.axis_v[q]
        n = cq.normal[q]
        r_eu = rx * eu[:, 0] + ry * eu[:, 1] + eu[:, 2]
        r_ev = rx * ev[:, 0] + ry * ev[:, 1] + ev[:, 2]
        r_n = rx * n[:, 0] + ry * n[:, 1] + n[:, 2]
        a = z * r_eu - cq.o_dot_u[q]
        b = z * r_ev - cq.o_dot_v[q]
        # d(a, b) per sub-pixel step: dX/dx_n = z (e_x - r n_x / (n . r)), x_n = 1 / (fx ss) per step
        kx = z / (camera.fx * ss)
        ky = z / (camera.fy * ss)
        da_dx = kx * (eu[:, 0] - r_eu * n[:, 0] / r_n)
        db_dx = kx * (ev[:, 0] - r_ev * n[:, 0] / r_n)
        da_dy = ky * (eu[:, 1] - r_eu * n[:, 1] / r_n)
        db_dy = ky * (ev[:, 1] - r_ev * n[:, 1] / r_n)
        mat_ids = scene.material[q]
        order = np.argsort(mat_ids, kind="stable")
        bounds = np.flatnonzero(np.diff(mat_ids[order])) + 1
        colour = np.empty((len(q), 3), dtype=np.float32)
        for sel in np.split(order, bounds):
            mat = scene.materials[int(mat_ids[sel[0]])]
            tex = scene.textures[mat.texture]
            qs = q[sel]
            su, sv = scene.texel_scale[qs, 0], scene.texel_scale[qs, 1]
            s = a[sel] * su + scene.texel_offset[qs, 0]
            t = b[sel] * sv + scene.texel_offset[qs, 1]
            c = sample_texture(tex, s, t, da_dx[sel] * su, db_dx[sel] * sv, da_dy[sel] * su, db_dy[sel] * sv,
                               max_aniso=settings.max_aniso) / np.float32(255.0)
            if mat.contrast != 1.0:
                mean = tex.data[tex.offsets[-1]].astype(np.float32) / np.float32(255.0)
                c = mean + np.float32(mat.contrast) * (c - mean)
            c = c * np.asarray(mat.tint, dtype=np.float32)
            if mat.macro is not None and mat.macro_strength > 0:
                mtex = scene.textures[mat.macro]
                rho = mtex.width / mat.macro_tile_m
                foot = np.maximum.reduce([np.abs(da_dx[sel]), np.abs(db_dx[sel]), np.abs(da_dy[sel]),
                                          np.abs(db_dy[sel])]) * rho
                m = sample_trilinear(mtex, a[sel] * rho, b[sel] * rho, np.log2(np.maximum(foot, 1e-12))).mean(1)
                m_mean = float(mtex.data[mtex.offsets[-1]].astype(np.float32).mean())
                factor = 1.0 + mat.macro_strength * (m / max(m_mean, 1.0) - 1.0)
                c = c * np.clip(factor, 0.2, 2.0)[:, None].astype(np.float32)
            colour[sel] = c
        colour *= scene.shade[q][:, None].astype(np.float32)
        if scene.fog_m > 0:
            dist = z * np.sqrt(rx * rx + ry * ry + 1.0)
            f = np.exp(-dist / scene.fog_m).astype(np.float32)[:, None]
            colour = colour * f + np.asarray(settings.sky_horizon, dtype=np.float32) * (1 - f)
        out[ii, jj] = colour
    if scene.sky:
        mi, mj = np.nonzero(qid < 0)
        if len(mi):
            d_c = np.stack([rx_all[mj], ry_all[mi], np.ones(len(mi))], 1)
            d_w = d_c @ T_w_c[:3, :3].T
            elev = d_w[:, 2] / np.linalg.norm(d_w, axis=1)
            w = np.clip(elev / 0.6, 0.0, 1.0)[:, None] ** 0.7
            horizon = np.asarray(settings.sky_horizon)
            zenith = np.asarray(settings.sky_zenith)
            out[mi, mj] = (horizon * (1 - w) + zenith * w).astype(np.float32)
    return out


def render_view(scene: Scene, camera: Camera, T_w_c, *, settings: RenderSettings | None = None,
                noise_seed: int | Sequence[int] | None = None) -> RenderedView:
    """Render ``scene`` seen by ``camera`` at pose ``T_w_c: (4, 4)`` (camera-to-world, metres).

    Args:
        noise_seed: int or sequence of ints seeding the sensor noise
            (``numpy.random.default_rng``); required when ``settings.noise_dn > 0``.

    Returns:
        RenderedView with the (H, W, 3) uint8 RGB image and (H, W) float32 metres depth.
    """
    settings = RenderSettings() if settings is None else settings
    T_w_c = check_transform("T_w_c", T_w_c)
    if camera.is_distorted:
        raise InputError("the renderer supports undistorted cameras only")
    if settings.noise_dn > 0 and noise_seed is None:
        raise InputError("render_view: noise_seed is required when settings.noise_dn > 0")
    ss = int(settings.supersampling)
    near = settings.near_m
    cq = _to_camera(scene, T_w_c, near)
    zbuf, qid = _visibility(scene, cq, camera, ss, near)
    if ss % 2 == 1:
        centre = zbuf[ss // 2::ss, ss // 2::ss]
    else:
        centre, _ = _visibility(scene, cq, camera, 1, near)
    depth = np.where(np.isfinite(centre), centre, 0.0).astype(np.float32)
    colour = _shade(scene, cq, camera, T_w_c, ss, zbuf, qid, settings)
    h, w = camera.height, camera.width
    img = colour.reshape(h, ss, w, ss, 3).mean(axis=(1, 3)) * 255.0
    if settings.noise_dn > 0:
        img = img + settings.noise_dn * np.random.default_rng(noise_seed).standard_normal(img.shape)
    return RenderedView(np.clip(np.rint(img), 0, 255).astype(np.uint8), depth)
