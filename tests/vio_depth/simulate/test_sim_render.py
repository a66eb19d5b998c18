"""Ray-cast renderer: deterministic output and geometrically exact depth."""

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_core.geometry import invert_transform, transform_points
from vio_depth.simulate.render import RenderSettings, render_depth, render_view
from vio_depth.simulate.scene_library import build_scene, tiny_scene
from vio_depth.simulate.textures import build_mip_texture, make_tileable, sample_texture, sample_trilinear

CAM = Camera(96, 72, 80.0, 80.0, 47.5, 35.5)


def look(position, yaw_deg, pitch_deg, roll_deg=0.0):
    """Camera-to-world pose of a camera at ``position`` looking along +y turned by yaw (left
    positive, about world z) and pitch (down positive)."""
    base = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # x_c -> +x, y_c -> -z, z_c -> +y
    R = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix() @ base @ \
        Rotation.from_euler("xz", [-pitch_deg, roll_deg], degrees=True).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(0)


def test_render_is_deterministic(scene):
    T = look([0.2, 0.0, 1.2], 5, 10)
    a = render_view(scene, CAM, T, noise_seed=3)
    b = render_view(tiny_scene(0), CAM, T, noise_seed=3)
    assert a.image.tobytes() == b.image.tobytes() and a.depth.tobytes() == b.depth.tobytes()
    c = render_view(scene, CAM, T, noise_seed=4)
    assert c.image.tobytes() != a.image.tobytes() and c.depth.tobytes() == a.depth.tobytes()
    assert a.image.dtype == np.uint8 and a.image.shape == (72, 96, 3)
    assert a.image.std() > 20  # textured, not flat


def test_depth_is_geometrically_exact_between_views(scene):
    T_a = look([0.2, 0.0, 1.2], 5, 0)
    T_b = look([0.7, 0.6, 1.0], -10, 4, 3)
    depth_a = render_view(scene, CAM, T_a, noise_seed=0).depth.astype(np.float64)
    depth_b = render_depth(scene, CAM, T_b)
    assert (depth_a > 0).mean() > 0.5 and (depth_a == 0).any()  # surfaces and sky
    v, u = np.nonzero(depth_a > 0)
    pts_a = CAM.backproject(np.stack([u, v], 1).astype(float), depth_a[v, u])
    pts_b = transform_points(invert_transform(T_b) @ T_a, pts_a)
    uv_b, z_b = CAM.project(pts_b)
    ok = (z_b > 0) & CAM.in_image(uv_b, margin=1.5)
    uv_b, z_b = uv_b[ok], z_b[ok]
    # 1/z is affine in pixel coordinates on a plane: bilinear interpolation of 1/depth is exact there
    x0 = np.floor(uv_b[:, 0]).astype(int)
    y0 = np.floor(uv_b[:, 1]).astype(int)
    fx, fy = uv_b[:, 0] - x0, uv_b[:, 1] - y0
    corners = np.stack([depth_b[y0, x0], depth_b[y0, x0 + 1], depth_b[y0 + 1, x0], depth_b[y0 + 1, x0 + 1]], 1)
    valid = (corners > 0).all(1)
    q = 1.0 / np.where(corners > 0, corners, np.inf)
    q_interp = (q[:, 0] * (1 - fx) * (1 - fy) + q[:, 1] * fx * (1 - fy) + q[:, 2] * (1 - fx) * fy
                + q[:, 3] * fx * fy)
    rel = np.abs(q_interp * z_b - 1.0)
    exact = valid & (rel < 1e-5)
    assert exact.sum() > 0.8 * valid.sum() and exact.sum() > 2000
    # the rest are occlusions or depth edges; no reprojected point may lie in front of B's surfaces
    neigh = np.stack([depth_b[y0 + dy, x0 + dx] for dy in (-1, 0, 1, 2) for dx in (-1, 0, 1, 2)], 1)
    nearest = np.where(neigh > 0, neigh, np.inf).min(1)
    assert np.mean(z_b[valid] < nearest[valid] - 0.01) < 0.002


def test_render_settings_validation_and_scene_names(scene):
    with pytest.raises(SettingsError):
        RenderSettings(supersampling=0)
    with pytest.raises(SettingsError):
        RenderSettings(max_aniso=3)
    with pytest.raises(InputError):
        render_view(scene, CAM, np.eye(4))  # noise needs a seed
    with pytest.raises(InputError):
        render_view(scene, Camera(8, 8, 5, 5, 4, 4, (0.1, 0, 0, 0)), np.eye(4), noise_seed=0)
    with pytest.raises(UnknownNameError, match="room, street, tiny"):
        build_scene("forest")
    odd = render_view(scene, CAM, look([0, 0, 1], 0, 5), settings=RenderSettings(supersampling=3, noise_dn=0))
    even = render_depth(scene, CAM, look([0, 0, 1], 0, 5))
    np.testing.assert_allclose(odd.depth, even, rtol=1e-6)  # odd supersampling reuses the centre rays


def test_texture_sampling_levels_and_tiling():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    tex = build_mip_texture("noise", img, size=16, tile=False)
    assert tex.levels == 5 and tex.widths.tolist() == [16, 8, 4, 2, 1]
    s = np.array([0.5, 3.5, 15.5])
    t = np.array([0.5, 7.5, 2.5])
    np.testing.assert_allclose(sample_trilinear(tex, s, t, np.zeros(3)),
                               img[t.astype(int), s.astype(int)].astype(np.float32))
    np.testing.assert_allclose(sample_trilinear(tex, s, t, np.full(3, 4.0)),
                               np.tile(img.reshape(-1, 3).mean(0), (3, 1)), atol=0.6)
    # a footprint far bigger than the texture averages it (anisotropic taps along x)
    big = sample_texture(tex, s, t, np.full(3, 64.0), np.zeros(3), np.zeros(3), np.full(3, 64.0))
    np.testing.assert_allclose(big, np.tile(img.reshape(-1, 3).mean(0), (3, 1)), atol=0.6)
    # tileable: the wrap-around step is no larger than typical neighbour steps
    smooth = ndimage.gaussian_filter(rng.normal(size=(64, 64)), 3.0, mode="nearest")[:, :, None]
    tiled = make_tileable(smooth)
    inner = np.abs(np.diff(tiled, axis=1)).mean()
    wrap = np.abs(tiled[:, 0] - tiled[:, -1]).mean()
    assert wrap < 2 * inner
    assert np.abs(tiled[0] - tiled[-1]).mean() < 2 * np.abs(np.diff(tiled, axis=0)).mean()
    assert np.abs(smooth[:, 0] - smooth[:, -1]).mean() > 5 * np.abs(np.diff(smooth, axis=1)).mean()
