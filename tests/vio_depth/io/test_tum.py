"""TUM RGB-D loader on tiny synthetic folders written to a temp dir."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import InputError, SequenceFormatError
from vio_depth.io import open_sequence
from vio_depth.io.tables import associate_nearest
from vio_depth.io.tum import TUM_CAMERAS, TumRgbdSequence, TumSettings
from vio_depth.pipeline import create_pose_source

W, H = 64, 48
T0 = 1305031102.0


def _true_pose(t):
    """Smooth ground-truth trajectory: camera-to-world at time t (seconds since T0)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.3 * t, 0.1 * t]).as_matrix()
    T[:3, 3] = [0.5 * t, -0.2 * t, 1.0 + 0.1 * t]
    return T


def write_tum(root, n=6, rgb_dt=1 / 30, depth_offset=0.004, gt_offset=0.0, gt_rate=100.0, gt_span=None,
              skip_depth=(), camera_txt=None):
    root.mkdir(parents=True, exist_ok=True)
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for i in range(n):
        t = T0 + i * rgb_dt
        img = np.full((H, W, 3), 10 * i, np.uint8)
        img[..., 2] = 200  # blue in RGB order
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), img[..., ::-1])
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        if i in skip_depth:
            continue
        td = t + depth_offset
        depth = np.full((H, W), 5000 * (1.0 + 0.5 * i), np.uint16)
        depth[0, 0] = 0
        cv2.imwrite(str(root / "depth" / f"{td:.6f}.png"), depth)
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    span = gt_span if gt_span is not None else n * rgb_dt + 0.1
    gt_lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for k in range(int(span * gt_rate) + 1):
        t = k / gt_rate - 0.05 + gt_offset
        T = _true_pose(t)
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        gt_lines.append(f"{T0 + t:.4f} " + " ".join(f"{v:.6f}" for v in [*T[:3, 3], *q]))
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    (root / "accelerometer.txt").write_text(
        "# accelerometer data\n" + "".join(f"{T0 + k / 100:.4f} 0.1 -9.8 0.2\n" for k in range(30)))
    if camera_txt is not None:
        (root / "camera.txt").write_text(camera_txt)
    return root


def test_open_associates_and_reads(tmp_path):
    root = write_tum(tmp_path / "rgbd_dataset_freiburg1_xyz")
    seq = open_sequence(root)
    assert isinstance(seq, TumRgbdSequence) and seq.format_name == "tum_rgbd"
    assert len(seq) == 6 and seq.dropped == 0
    assert seq.has_gt_depth
    f = seq[2]
    img = f.image()
    assert img.shape == (H, W, 3) and img.dtype == np.uint8 and img[0, 0, 2] == 200
    d = f.gt_depth()
    assert d.dtype == np.float32 and d[0, 0] == 0.0
    assert d[5, 5] == pytest.approx(2.0)  # 5000 * 2.0 / 5000
    # pose interpolated at the colour timestamp (ground truth sampled at 100 Hz)
    np.testing.assert_allclose(f.T_w_c, _true_pose(f.timestamp - T0), atol=2e-4)
    assert f.timestamp == pytest.approx(T0 + 2 / 30, abs=1e-6)
    assert f.stem == f"{T0 + 2 / 30:.6f}"
    t_acc, acc = seq.accelerometer
    assert acc.shape == (30, 3) and acc[0, 1] == pytest.approx(-9.8)


def test_known_freiburg_cameras_and_camera_txt(tmp_path):
    fr1 = TumRgbdSequence(write_tum(tmp_path / "rgbd_dataset_freiburg1_desk"))
    assert fr1.camera.is_distorted and fr1.camera.dist == TUM_CAMERAS["freiburg1"].dist
    # the synthetic images are 64x48: the 640x480 calibration is scaled to them
    assert fr1.camera.fx == pytest.approx(517.3 * W / 640)
    fr3 = TumRgbdSequence(write_tum(tmp_path / "rgbd_dataset_freiburg3_office"))
    assert not fr3.camera.is_distorted
    own_cam = "# fx fy cx cy k1 k2 p1 p2\n50 51 31.5 23.5 0.1 -0.2 0.001 0.002\n"
    own = TumRgbdSequence(write_tum(tmp_path / "freiburg2_but_own_file", camera_txt=own_cam))
    assert (own.camera.fx, own.camera.fy, own.camera.cx, own.camera.cy) == (50, 51, 31.5, 23.5)
    assert own.camera.dist == (0.1, -0.2, 0.001, 0.002)
    with pytest.raises(SequenceFormatError, match="camera.txt"):
        TumRgbdSequence(write_tum(tmp_path / "my_kinect_recording"))
    with pytest.raises(SequenceFormatError, match="camera.txt"):
        TumRgbdSequence(write_tum(tmp_path / "bad_cam_freiburg1", camera_txt="50 51 31.5\n"))


def test_frames_without_partner_are_dropped(tmp_path):
    seq = TumRgbdSequence(write_tum(tmp_path / "freiburg1_x", skip_depth=(0, 3)))
    assert len(seq) == 4 and seq.dropped == 2
    assert seq[0].timestamp == pytest.approx(T0 + 1 / 30, abs=1e-6)


def test_tolerance_setting(tmp_path):
    root = write_tum(tmp_path / "freiburg1_y", rgb_dt=0.1, depth_offset=0.03)
    with pytest.raises(SequenceFormatError, match="depth.txt"):
        TumRgbdSequence(root)  # 30 ms > default 20 ms
    assert len(TumRgbdSequence(root, TumSettings(max_time_difference=0.035))) == 6


@pytest.mark.parametrize("kwargs, name", [
    (dict(depth_offset=1.0), "depth.txt"),
    (dict(gt_offset=5.0), "groundtruth.txt"),
])
def test_unassociable_timestamps_name_the_file(tmp_path, kwargs, name):
    root = write_tum(tmp_path / "freiburg1_z", **kwargs)
    with pytest.raises(SequenceFormatError, match=name) as e:
        open_sequence(root)
    assert str(root / name) in str(e.value)


def test_malformed_lines_name_file_and_line(tmp_path):
    root = write_tum(tmp_path / "freiburg1_w")
    lines = (root / "groundtruth.txt").read_text().splitlines()
    lines[4] = lines[4].rsplit(" ", 2)[0]  # truncated pose line
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match=r"groundtruth.txt:5: expected 8 columns \(t tx ty tz qx qy qz qw\), got 6"):
        open_sequence(root, format="tum_rgbd")
    (root / "groundtruth.txt").unlink()
    (root / "depth.txt").write_text("1305031102.0 depth/a.png\nnot_a_time depth/b.png\n")
    with pytest.raises(SequenceFormatError, match=r"depth.txt:2: non-numeric"):
        open_sequence(root)


def test_imu_pose_source_is_refused(tmp_path):
    seq = open_sequence(write_tum(tmp_path / "freiburg1_v"))
    assert seq.imu is None
    with pytest.raises(InputError, match="sequence has no IMU.*gyroscope"):
        create_pose_source("imu", seq)


def test_associate_nearest():
    ref = np.array([0.0, 0.1, 0.2, 0.3])
    got = associate_nearest(np.array([-0.5, 0.04, 0.06, 0.29, 0.35]), ref, 0.02)
    assert got.tolist() == [-1, -1, -1, 3, -1]
    got = associate_nearest(np.array([0.04, 0.06]), ref, 0.05)
    assert got.tolist() == [0, 1]


def test_real_tum_folder_whatever_its_name_and_through_a_symlink(tmp_path):
    """A renamed real TUM folder is recognised by rgb.txt's header; a symlink keeps its name."""
    renamed = write_tum(tmp_path / "my_recording")
    rgb = renamed / "rgb.txt"
    rgb.write_text("# color images\n# file: 'rgbd_dataset_freiburg1_rpy.bag'\n" + rgb.read_text())
    seq = open_sequence(renamed)
    assert isinstance(seq, TumRgbdSequence) and seq.camera.dist == TUM_CAMERAS["freiburg1"].dist
    target = write_tum(tmp_path / "data_0001")
    link = tmp_path / "rgbd_dataset_freiburg2_desk"
    link.symlink_to(target, target_is_directory=True)
    seq = open_sequence(link)
    assert seq.name == "rgbd_dataset_freiburg2_desk"
    assert seq.camera.dist == TUM_CAMERAS["freiburg2"].dist
