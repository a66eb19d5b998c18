"""ROS bags as sequences (ROS 1, ROS 2 SQLite3, ROS 2 MCAP, bare .mcap): the same frames as the
ASL folder they were written from, every image encoding and camera model, and one clear
error for every bad bag."""

import shutil
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError
from vio_depth.cli import main
from vio_depth.io import BagSettings, open_bag, open_sequence, read_calibration
from vio_depth.io.bag_topics import format_inspection, inspect_bag
from vio_depth.io.bag_writer import BagWriter, asl_to_bag
from vio_depth.io.kalibr import write_camchain, write_imu_yaml

pytest.importorskip("skimage")  # the ASL sample's textures

#: camera-to-IMU mounting with an axis-permutation rotation and dyadic translation: every
#: transform the ASL and bag loaders compute is then exact, so their poses are bit-identical
T_I_C = np.array([[0.0, 0.0, 1.0, 0.0625], [-1.0, 0.0, 0.0, -0.03125], [0.0, -1.0, 0.0, 0.015625], [0, 0, 0, 1.0]])
KINDS = {"ros1": "room.bag", "ros2": "room_sqlite3", "mcap": "room_mcap"}
CAMERA = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    """A SIMULATED ASL folder (6 frames of the room, 1/4 size, 17-column ground truth), its
    Kalibr files and a bag of it of each kind."""
    from vio_depth.simulate.asl import generate_asl_sample

    base = tmp_path_factory.mktemp("bags")
    root = generate_asl_sample(base / "asl", n_frames=6, scale=0.25, T_i_c=T_I_C)
    seq = open_sequence(root)
    write_camchain(base / "camchain.yaml", seq.camera, seq.imu.T_c_i, rostopic="/cam0/image_raw")
    write_imu_yaml(base / "imu.yaml", seq.imu, rostopic="/imu0")
    for kind, name in KINDS.items():
        asl_to_bag(root, base / name, kind)
    return base


def _calib(base):
    return read_calibration(base / "camchain.yaml", base / "imu.yaml")


def _assert_same_frames(bag, seq, images=True):
    assert len(bag) == len(seq) and bag.camera == seq.camera
    for fb, fa in zip(bag, seq):
        assert (fb.index, fb.stem, fb.timestamp) == (fa.index, fa.stem, fa.timestamp)
        assert (fb.T_w_c is None) == (fa.T_w_c is None)
        if fa.T_w_c is not None:
            assert np.array_equal(fb.T_w_c, fa.T_w_c)
        if images:
            assert np.array_equal(fb.image(), fa.image())
    for name in ("t", "gyro", "accel", "T_c_i"):
        assert np.array_equal(getattr(bag.imu, name), getattr(seq.imu, name)), name
    for name in ("gyro_noise", "accel_noise", "gyro_bias_walk", "accel_bias_walk", "gravity_w"):
        assert getattr(bag.imu, name) == getattr(seq.imu, name), name


@pytest.mark.parametrize("kind", list(KINDS))
def test_each_kind_of_bag_gives_the_asl_folders_frames_bit_for_bit(sample, kind):
    seq = open_sequence(sample / "asl")
    bag = open_bag(sample / KINDS[kind], BagSettings(calibration=_calib(sample)))
    assert bag.format_name == "rosbag" and bag.topics.image == "/cam0/image_raw" and bag.topics.pose == "/groundtruth"
    _assert_same_frames(bag, seq)
    assert bag.n_posed == len(bag)


def test_bare_mcap_and_db3_files_open_and_are_detected(sample):
    seq = open_sequence(sample / "asl")
    for path in (next((sample / "room_mcap").glob("*.mcap")), next((sample / "room_sqlite3").glob("*.db3"))):
        with pytest.raises(InputError, match="poses of /groundtruth are of the IMU frame"):
            open_sequence(path)  # detected as a bag; its poses need the extrinsic
        auto = open_bag(path, BagSettings(pose_topic="none"))
        assert len(auto) == len(seq) and auto.imu is None and "T_cam_imu" in auto.imu_missing_reason
        _assert_same_frames(open_bag(path, BagSettings(calibration=_calib(sample))), seq)
    assert open_bag(sample / "room.bag", BagSettings(pose_topic="none")).kind == "ROS 1 bag"


@pytest.mark.parametrize("image_form, pose_form", [("png", "transform"), ("raw", "odometry")])
def test_compressed_images_and_other_pose_messages(sample, tmp_path, image_form, pose_form):
    seq = open_sequence(sample / "asl")
    asl_to_bag(sample / "asl", tmp_path / "b.bag", "ros1", image_form=image_form, pose_form=pose_form)
    bag = open_bag(tmp_path / "b.bag", BagSettings(calibration=_calib(sample)))
    _assert_same_frames(bag, seq)
    if pose_form == "odometry":  # the twist, in the body frame, comes back as the world velocity
        for fb, fa in zip(bag, seq):
            np.testing.assert_allclose(fb.velocity_w, fa.velocity_w, atol=1e-12)


def test_camera_poses_and_threads_reading_at_once(sample, tmp_path):
    seq = open_sequence(sample / "asl")
    with BagWriter(tmp_path / "c.bag", "ros1") as w:
        m = w.messages
        for f in seq:
            w.write("/cam0/image_raw", m.image(int(f.stem), "cam0", f.image()[:, :, 0].copy(), "mono8"))
            w.write("/cam0/camera_info", m.camera_info(int(f.stem), "cam0", seq.camera))
            for dt in (-2_000_000, 2_000_000):  # camera poses 2 ms around each frame (the same pose)
                w.write("/camera_pose", m.pose_stamped(int(f.stem) + dt, "world", f.T_w_c[:3, 3], _q_wxyz(f.T_w_c)))
    bag = open_bag(tmp_path / "c.bag", BagSettings(pose_frame="camera"))
    assert bag.imu is None and "no sensor_msgs/Imu topic" in bag.imu_missing_reason
    for fb, fa in zip(bag, seq):
        np.testing.assert_allclose(fb.T_w_c, fa.T_w_c, atol=1e-12)
    with ThreadPoolExecutor(4) as pool:
        images = list(pool.map(lambda i: bag[i % len(bag)].image(), range(4 * len(bag))))
    for i, image in enumerate(images):
        assert np.array_equal(image, seq[i % len(seq)].image())
    bag.close()
    with pytest.raises(InputError, match="closed"):
        bag[0].image()


def _q_wxyz(T):
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return [w, x, y, z]


# --------------------------------------------------------------------------- encodings, camera models
def _one_image_bag(path, kind, msg_of, camera=CAMERA, info=True):
    with BagWriter(path, kind) as w:
        for k in range(2):
            t = 1_000_000_000 + k * 50_000_000
            w.write("/cam/image", msg_of(w.messages, t))
            if info:
                w.write("/cam/camera_info", w.messages.camera_info(t, "cam", camera))
    return path


RGB = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)


@pytest.mark.parametrize("encoding, pixels, expected", [
    ("rgb8", RGB, RGB),
    ("bgr8", RGB[:, :, ::-1], RGB),
    ("mono8", RGB[:, :, 0], np.repeat(RGB[:, :, :1], 3, axis=2)),
    ("mono16", RGB[:, :, 0].astype(np.uint16) * 257, np.repeat(RGB[:, :, :1], 3, axis=2)),
    ("16UC1", RGB[:, :, 1].astype(np.uint16) * 257 + 100, np.repeat(RGB[:, :, 1:2], 3, axis=2)),
])
def test_raw_image_encodings(tmp_path, encoding, pixels, expected):
    path = _one_image_bag(tmp_path / "e.bag", "ros1", lambda m, t: m.image(t, "cam", np.ascontiguousarray(pixels),
                                                                            encoding))
    assert np.array_equal(open_bag(path)[1].image(), expected)


@pytest.mark.parametrize("ext, pixels, expected", [
    (".png", RGB[:, :, ::-1], RGB),
    (".png", RGB[:, :, 2].astype(np.uint16) * 257, np.repeat(RGB[:, :, 2:3], 3, axis=2)),
])
def test_compressed_png_8_and_16_bit(tmp_path, ext, pixels, expected):
    data = cv2.imencode(ext, np.ascontiguousarray(pixels))[1].tobytes()
    path = _one_image_bag(tmp_path / "p_mcap", "mcap", lambda m, t: m.compressed_image(t, "cam", data, "png"))
    assert np.array_equal(open_bag(path)[0].image(), expected)


def test_a_step_wider_than_the_row_and_big_endian_16_bit(tmp_path):
    def padded(m, t):
        msg = m.image(t, "cam", RGB[:, :, 0].astype(np.uint16) * 257, "mono16")
        rows = msg.data.reshape(6, 16).view("<u2").astype(">u2").view(np.uint8)
        msg.data = np.hstack([rows, np.full((6, 4), 7, np.uint8)]).reshape(-1)
        msg.step, msg.is_bigendian = 20, 1
        return msg
    path = _one_image_bag(tmp_path / "s_sqlite3", "ros2", padded)
    assert np.array_equal(open_bag(path)[0].image(), np.repeat(RGB[:, :, :1], 3, axis=2))


@pytest.mark.parametrize("camera", [
    Camera(8, 6, 10.0, 11.0, 3.5, 2.5, (-0.01, 0.001, 0.0001, -0.0002, 0.0005)),
    Camera(8, 6, 10.0, 11.0, 3.5, 2.5, (0.01, -0.002, 0.001, 0.0001), "equidistant"),
    Camera(8, 6, 10.0, 11.0, 3.5, 2.5, (-0.01, 0.001, 0.0001, -0.0002, 0.0005, 0.001, 0.0, 0.0)),
])
def test_camera_info_models(tmp_path, camera):
    path = _one_image_bag(tmp_path / "c.bag", "ros1", lambda m, t: m.image(t, "cam", RGB, "rgb8"), camera=camera)
    assert open_bag(path).camera == camera


def test_a_rectified_topic_takes_p_and_no_distortion(tmp_path):
    cam = Camera(8, 6, 10.0, 11.0, 3.5, 2.5, (-0.01, 0.001, 0.0001, -0.0002))
    with BagWriter(tmp_path / "r.bag", "ros1") as w:
        info = w.messages.camera_info(1_000_000_000, "cam", cam)
        info.P = np.array([9.0, 0, 3.25, 0, 0, 9.0, 2.75, 0, 0, 0, 1, 0])
        w.write("/cam/image_rect", w.messages.image(1_000_000_000, "cam", RGB, "rgb8"))
        w.write("/cam/camera_info", info)
    assert open_bag(tmp_path / "r.bag").camera == Camera(8, 6, 9.0, 9.0, 3.25, 2.75)


# --------------------------------------------------------------------------- bad bags: one line, exit 1
def _stamped_bag(path, stamps, bag_times=None, encoding="rgb8"):
    with BagWriter(path, "ros1") as w:
        for k, t in enumerate(stamps):
            w.write("/cam/image", w.messages.image(t, "cam", RGB, encoding) if encoding != "yuv422" else
                    _yuv(w.messages, t), None if bag_times is None else bag_times[k])
            w.write("/cam/camera_info", w.messages.camera_info(t, "cam", CAMERA))
    return path


def _yuv(m, t):
    msg = m.image(t, "cam", RGB[:, :, :2].reshape(6, 16).copy(), "mono8")
    msg.encoding, msg.width, msg.step = "yuv422", 8, 16
    return msg


@pytest.mark.parametrize("make, settings, message", [
    (lambda p: _stamped_bag(p, [2, 1], [10, 11]), {}, "header stamps do not increase at message 1"),
    (lambda p: _stamped_bag(p, [10**9, 10**9 + 5 * 10**9], [10**9, 10**9 + 10**8]), {}, "clock jump at message 1"),
    (lambda p: _stamped_bag(p, [10**9, 2 * 10**9], encoding="yuv422"), {}, "unsupported image encoding 'yuv422'"),
    (lambda p: _stamped_bag(p, [0, 10]), {}, "no header stamp"),
    (lambda p: _stamped_bag(p, [10**9]), {"image_topic": "/cam0/image_raw"}, "no topic /cam0/image_raw"),
    (lambda p: _stamped_bag(p, [10**9]), {"image_topic": "/cam/camera_info"}, "carries sensor_msgs/msg/CameraInfo"),
    (lambda p: _stamped_bag(p, [10**9]), {"imu_topic": "/imu0"}, r"no topic /imu0 \(--imu-topic\)"),
    (lambda p: _stamped_bag(p, [10**9]), {"camera_info_topic": "none"}, "no camera calibration"),
])
def test_bad_bags_are_refused_with_one_clear_line(tmp_path, make, settings, message):
    path = make(tmp_path / "bad.bag")
    with pytest.raises(InputError, match=message) as info:
        open_bag(path, BagSettings(**settings))
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_empty_truncated_misnamed_and_ambiguous_bags(sample, tmp_path):
    with BagWriter(tmp_path / "empty.bag", "ros1"):
        pass
    with pytest.raises(InputError, match="holds no message"):
        open_bag(tmp_path / "empty.bag")
    data = (sample / "room.bag").read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2])
    mcap = next((sample / "room_mcap").glob("*.mcap")).read_bytes()
    (tmp_path / "cut.mcap").write_bytes(mcap[: len(mcap) // 2])
    for name in ("cut.bag", "cut.mcap"):
        with pytest.raises(InputError, match="cannot read the bag|no message|truncated") as info:
            open_bag(tmp_path / name)
        assert "\n" not in str(info.value)
    shutil.copy(sample / "room.bag", tmp_path / "room.data")
    with pytest.raises(InputError, match=r"a ROS 1 bag, but not named \*.bag"):
        open_bag(tmp_path / "room.data")
    with BagWriter(tmp_path / "two.bag", "ros1") as w:
        for topic in ("/left/image", "/right/image"):
            w.write(topic, w.messages.image(10**9, "cam", RGB, "rgb8"))
    with pytest.raises(InputError, match=r"several topics could serve as image \(/left/image, /right/image\): "
                                         r"choose one with --image-topic"):
        open_bag(tmp_path / "two.bag")


def test_imu_frame_poses_need_the_extrinsic(sample):
    with pytest.raises(InputError, match="poses of /groundtruth are of the IMU frame"):
        open_bag(sample / "room.bag", BagSettings(calibration=read_calibration(imu_yaml=sample / "imu.yaml")))
    bag = open_bag(sample / "room.bag", BagSettings(pose_topic="none"))
    assert bag.n_posed == 0 and bag.imu is None


def test_cli_inspect_and_one_line_errors(sample, tmp_path, capsys):
    assert main(["inspect", str(sample / "room_mcap")]) == 0
    out = capsys.readouterr().out
    assert "ROS 2 bag (mcap)" in out and "/cam0/image_raw" in out and "sensor_msgs/msg/Imu" in out
    assert " 200.0 Hz" in out and "a run would use: image: /cam0/image_raw" in out
    assert "a run needs for --poses imu / vio: --calib camchain.yaml with T_cam_imu and --imu-calib" in out
    text = format_inspection(inspect_bag(sample / "room.bag", BagSettings(image_topic="/nope")))
    assert "a run would fail: no topic /nope (--image-topic)" in text
    bad = _stamped_bag(tmp_path / "bad.bag", [2, 1], [10, 11])
    for argv in (["run", str(bad), "--out", str(tmp_path / "o")],
                 ["run", str(sample / "room.bag"), "--image-topic", "/x", "--out", str(tmp_path / "o")],
                 ["run", str(sample / "asl"), "--image-topic", "/x", "--out", str(tmp_path / "o")],
                 ["inspect", str(tmp_path / "missing.bag")]):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("vio-depth: error:"), err
        assert not (tmp_path / "o").exists()
