"""The ROS outputs on their own: nameable topics and frames, exact values, equidistant cameras,
frames without depth, stamps of sequences whose stems are not stamps."""

from types import SimpleNamespace

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import SettingsError
from vio_depth.evaluation import CameraTrajectory
from vio_depth.export.rosout import RosOutputSettings, RosRunWriter, frame_stamp_ns

CAMERA = Camera(6, 4, 5.0, 5.0, 2.5, 1.5, (0.01, -0.002, 0.001, 0.0001), "equidistant")


def _frame(i, stem=None):
    return SimpleNamespace(index=i, timestamp=10.0 + 0.1 * i, stem=stem or f"{i:06d}", camera=CAMERA)


def _result(depth, uv=None):
    n = 0 if uv is None else len(uv)
    return SimpleNamespace(depth=depth, disparity=None, fit=None, points_uv=uv,
                           points_depth=np.linspace(1.0, 2.0, n), points_sigma=None, points_inlier=None)


def test_named_topics_frames_and_exact_values(tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    settings = RosOutputSettings(prefix="/robot/depth_net", world_frame="map", camera_frame="cam_optical",
                                 depth_topic="/depth_registered/image")
    writer = RosRunWriter(tmp_path / "x.mcap", "mcap", settings)
    depth = np.random.default_rng(1).uniform(0.5, 300.0, (4, 6)).astype(np.float32)
    depth[0, 0] = np.nan
    writer.add_frame(_frame(0), _result(None))  # no depth: nothing
    writer.add_frame(_frame(1), _result(depth, np.array([[1.0, 1.0], [4.0, 2.0]])))
    writer.add_frame(_frame(1), _result(depth))  # already written: nothing
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    writer.finish(_Seq(), CameraTrajectory(np.array([10.1]), T[None]))
    with open(tmp_path / "x.mcap", "rb") as fh:
        got = {c.topic: m for _, c, _, m in make_reader(fh, decoder_factories=[DecoderFactory()])
               .iter_decoded_messages()}
    assert set(got) == {"/depth_registered/image", "/robot/depth_net/depth_kitti", "/robot/depth_net/camera_info",
                        "/robot/depth_net/points", "/robot/depth_net/pose", "/tf"}
    d = got["/depth_registered/image"]
    assert d.header.frame_id == "cam_optical" and d.header.stamp.sec == 10 and d.header.stamp.nanosec == 100_000_000
    assert np.array_equal(np.frombuffer(bytes(d.data), "<f4").reshape(4, 6).view(np.uint32), depth.view(np.uint32))
    kitti = np.frombuffer(bytes(got["/robot/depth_net/depth_kitti"].data), "<u2").reshape(4, 6)
    assert kitti[0, 0] == 0 and kitti[1, 1] == min(65535, round(float(depth[1, 1]) * 256))
    info = got["/robot/depth_net/camera_info"]
    assert info.distortion_model == "equidistant" and list(info.d) == list(CAMERA.dist)
    pts = np.frombuffer(bytes(got["/robot/depth_net/points"].data),
                        [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("sigma", "<f4"), ("inlier", "u1")])
    assert np.allclose(pts["z"], [1.0, 2.0]) and np.all(np.isnan(pts["sigma"])) and np.all(pts["inlier"] == 1)
    ideal = CAMERA.undistort_points(np.array([[1.0, 1.0], [4.0, 2.0]]))
    np.testing.assert_allclose(pts["x"] / pts["z"], (ideal[:, 0] - 2.5) / 5.0, atol=1e-6)
    pose = got["/robot/depth_net/pose"]
    assert pose.header.frame_id == "map" and (pose.pose.position.x, pose.pose.position.z) == (1.0, 3.0)
    assert got["/tf"].transforms[0].child_frame_id == "cam_optical"


class _Seq:
    def __len__(self):
        return 2

    def frame(self, i):
        return _frame(i)


def test_stamps_and_settings():
    assert frame_stamp_ns(SimpleNamespace(stem="1600000000750000000", timestamp=1600000000.75)) == 1600000000750000000
    assert frame_stamp_ns(SimpleNamespace(stem="000012", timestamp=1.2)) == 1_200_000_000
    with pytest.raises(SettingsError, match="must start with '/'"):
        RosOutputSettings(prefix="vio")
    with pytest.raises(SettingsError, match="a frame id"):
        RosOutputSettings(camera_frame="a/b")
