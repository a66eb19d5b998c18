"""PLY clouds: read back with plyfile, exact values, world-frame geometry on a synthetic scene."""

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError, ShapeError
from vio_core.geometry import invert_transform, make_transform, transform_points
from vio_depth.export import PointCloud, dense_cloud, encode_ply, sparse_cloud, write_ply

plyfile = pytest.importorskip("plyfile")

CAM = Camera(64, 48, 50.0, 52.0, 31.5, 23.5)
CAM_DISTORTED = Camera(640, 480, 500.0, 505.0, 319.5, 239.5, dist=(-0.3, 0.1, 0.001, -0.001))


def _pose(angle_deg=20.0, t=(1.0, -2.0, 0.5)):
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return make_transform(R, np.array(t))


def _image():
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)


def test_sparse_cloud_places_points_in_the_world_and_round_trips_exactly(tmp_path):
    rng = np.random.default_rng(0)
    T_w_c = _pose()
    points_c = np.stack([rng.uniform(-1, 1, 30), rng.uniform(-0.7, 0.7, 30), rng.uniform(2, 9, 30)], 1)
    points_w = transform_points(T_w_c, points_c)
    uv, z = CAM.project(points_c)
    sigma = rng.uniform(0.01, 0.2, 30)
    inlier = rng.random(30) < 0.7
    image = _image()
    cloud = sparse_cloud(CAM, T_w_c, uv, z, image=image, sigma_depth=sigma, inlier=inlier, frame_index=7)
    np.testing.assert_allclose(cloud.points_w, points_w, atol=1e-9)
    ui, vi = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    assert np.array_equal(cloud.rgb, image[vi, ui])

    write_ply(tmp_path / "s.ply", cloud, comments=("frame 7",))
    raw = (tmp_path / "s.ply").read_bytes()
    assert raw.startswith(b"ply\nformat binary_little_endian 1.0\n")
    ply = plyfile.PlyData.read(str(tmp_path / "s.ply"))
    v = ply["vertex"].data
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "red", "green", "blue", "sigma_depth",
                                                         "depth", "frame", "inlier"]
    assert len(v) == 30
    for k, name in enumerate("xyz"):
        assert np.array_equal(v[name], points_w[:, k].astype(np.float32))
    assert np.array_equal(np.stack([v["red"], v["green"], v["blue"]], 1), image[vi, ui])
    assert np.array_equal(v["sigma_depth"], sigma.astype(np.float32))
    assert np.array_equal(v["depth"], z.astype(np.float32))
    assert np.all(v["frame"] == 7) and np.array_equal(v["inlier"].astype(bool), inlier)
    assert any("frame 7" in c for c in ply.comments)


def test_raw_distorted_pixels_are_undistorted_before_backprojection():
    rng = np.random.default_rng(2)
    T_w_c = _pose(-35.0, (0.0, 3.0, -1.0))
    points_c = np.stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.0, 1.0, 40), rng.uniform(2.5, 5, 40)], 1)
    uv_ideal, z = CAM_DISTORTED.project(points_c)
    uv_raw = CAM_DISTORTED.distort_points(uv_ideal)
    assert np.max(np.abs(uv_raw - uv_ideal)) > 3.0  # the distortion matters here
    cloud = sparse_cloud(CAM_DISTORTED, T_w_c, uv_raw, z)
    np.testing.assert_allclose(cloud.points_w, transform_points(T_w_c, points_c), atol=1e-6)
    assert np.all(np.isnan(cloud.sigma_depth)) and cloud.inlier.all()
    assert np.all(cloud.rgb == 200)  # no image: grey


def test_dense_cloud_of_a_plane_lies_on_the_plane_with_stride_and_colours(tmp_path):
    T_w_c = _pose(10.0, (2.0, 0.0, 0.0))
    depth = np.full((48, 64), 4.0, np.float32)
    depth[:, :8] = np.nan  # invalid columns are skipped
    sigma = np.full((48, 64), 0.05, np.float32)
    image = _image()
    cloud = dense_cloud(CAM, T_w_c, depth, image=image, sigma_map=sigma, stride=4, frame_index=3)
    assert len(cloud) == 12 * 14  # rows 0,4..44; columns 8,12..60
    points_c = transform_points(invert_transform(T_w_c), cloud.points_w)
    np.testing.assert_allclose(points_c[:, 2], 4.0, atol=1e-9)
    uv, _ = CAM.project(points_c)
    assert np.allclose(uv, np.rint(uv), atol=1e-6) and np.all(np.rint(uv).astype(int) % 4 == 0)
    assert uv[:, 0].min() == pytest.approx(8.0)
    ui, vi = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    assert np.array_equal(cloud.rgb, image[vi, ui])
    assert np.allclose(cloud.sigma_depth, 0.05) and np.all(cloud.frame == 3)
    write_ply(tmp_path / "d.ply", cloud)
    v = plyfile.PlyData.read(str(tmp_path / "d.ply"))["vertex"].data
    assert np.array_equal(v["z"], cloud.points_w[:, 2].astype(np.float32))
    near = dense_cloud(CAM, T_w_c, depth, stride=1, max_depth=3.0)
    assert len(near) == 0


def test_merged_map_and_empty_cloud_read_back(tmp_path):
    T = _pose()
    a = sparse_cloud(CAM, T, np.array([[10.0, 10.0]]), np.array([2.0]), frame_index=0)
    b = sparse_cloud(CAM, T, np.array([[20.0, 30.0], [5.0, 6.0]]), np.array([3.0, 4.0]), frame_index=1)
    merged = PointCloud.concatenate([a, b])
    write_ply(tmp_path / "m.ply", merged)
    v = plyfile.PlyData.read(str(tmp_path / "m.ply"))["vertex"].data
    assert v["frame"].tolist() == [0, 1, 1]
    assert np.array_equal(v["x"], merged.points_w[:, 0].astype(np.float32))
    write_ply(tmp_path / "e.ply", PointCloud.concatenate([]))
    assert len(plyfile.PlyData.read(str(tmp_path / "e.ply"))["vertex"].data) == 0


def test_bad_inputs():
    with pytest.raises(ShapeError):
        sparse_cloud(CAM, np.eye(3), np.zeros((1, 2)), np.ones(1))
    with pytest.raises(ShapeError):
        sparse_cloud(CAM, np.eye(4), np.zeros((2, 2)), np.ones(3))
    with pytest.raises(SettingsError):
        dense_cloud(CAM, np.eye(4), np.ones((48, 64)), stride=0)
    with pytest.raises(InputError, match="does not match"):
        dense_cloud(CAM, np.eye(4), np.ones((10, 10)))
    with pytest.raises(InputError):
        encode_ply(np.zeros(3, dtype=[("x", "U3")]))
