"""KITTI raw loader: synthetic drives in a temp dir, and kitti_tiny when present."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import relative_transform
from vio_depth.evaluation.metrics import depth_reprojection_errors
from vio_depth.io import open_sequence
from vio_depth.io.kitti import KittiRawSequence, KittiSettings
from vio_depth.io.kitti_oxts import (
    EARTH_RADIUS_M,
    OXTS_FIELDS,
    load_kitti_calibration,
    oxts_poses,
    project_velodyne,
    read_velodyne_bin,
    retime_oxts_packets,
)

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "kitti_tiny"
F = {n: i for i, n in enumerate(OXTS_FIELDS)}
W, H = 80, 30
LAT0, LON0 = 49.0, 8.4

CAM_TO_CAM = f"""calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
R_rect_00: 1 0 0 0 1 0 0 0 1
P_rect_00: 60 0 39.5 0 0 60 14.5 0 0 0 1 0
S_rect_02: {W} {H}
R_rect_02: 1 0 0 0 1 0 0 0 1
P_rect_02: 60 0 39.5 3.0 0 60 14.5 0.0 0 0 1 0.0
"""
# velodyne: x forward, y left, z up; camera: x right, y down, z forward
VELO_TO_CAM = "calib_time: x\nR: 0 -1 0 0 0 -1 1 0 0\nT: 0.0 -0.1 -0.3\n"
IMU_TO_VELO = "calib_time: x\nR: 1 0 0 0 1 0 0 0 1\nT: -0.8 0.3 -0.8\n"


def enu_to_latlon(x, y):
    """Inverse of the KITTI Mercator recipe with the first packet's latitude LAT0."""
    s = np.cos(np.radians(LAT0))
    tx0 = s * np.radians(LON0) * EARTH_RADIUS_M
    ty0 = s * EARTH_RADIUS_M * np.log(np.tan(np.radians(90 + LAT0) / 2))
    lon = np.degrees((x + tx0) / (s * EARTH_RADIUS_M))
    lat = 2 * np.degrees(np.arctan(np.exp((y + ty0) / (s * EARTH_RADIUS_M)))) - 90
    return lat, lon


def make_packets(t, speed=8.0, yaw_rate=0.05):
    """OXTS packets of a car driving a gentle left curve at ``speed`` m/s, times ``t`` (N,) s."""
    yaw0 = 0.3
    yaw = yaw0 + yaw_rate * t
    # exact arc: x = (v / w)(sin(yaw) - sin(yaw0)), y = -(v / w)(cos(yaw) - cos(yaw0))
    x = speed / yaw_rate * (np.sin(yaw) - np.sin(yaw0))
    y = -speed / yaw_rate * (np.cos(yaw) - np.cos(yaw0))
    lat, lon = enu_to_latlon(x, y)
    p = np.zeros((len(t), len(OXTS_FIELDS)))
    p[:, F["lat"]], p[:, F["lon"]], p[:, F["alt"]] = lat, lon, 110.0
    p[:, F["roll"]], p[:, F["pitch"]], p[:, F["yaw"]] = 0.01, 0.02, yaw
    p[:, F["ve"]], p[:, F["vn"]] = speed * np.cos(yaw), speed * np.sin(yaw)
    p[:, F["vf"]] = speed
    p[:, F["az"]] = 9.81
    p[:, F["wz"]] = yaw_rate
    p[:, F["navstat"]] = 4
    return p, np.stack([x, y, np.full_like(x, 110.0)], 1)


def _stamp(t):
    base = 13 * 3600 + 17 * 60
    s = base + t
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"2011-09-26 {int(h):02d}:{int(m):02d}:{sec:012.9f}"


def write_drive(root, n=5, bins=True):
    """A synthetic ``<date>/<drive>_sync`` folder; returns (drive, image_times, true_T_w_i at image times)."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    for sub in ("image_02/data", "oxts/data", "velodyne_points/data"):
        (drive / sub).mkdir(parents=True)
    (date / "calib_cam_to_cam.txt").write_text(CAM_TO_CAM)
    (date / "calib_velo_to_cam.txt").write_text(VELO_TO_CAM)
    (date / "calib_imu_to_velo.txt").write_text(IMU_TO_VELO)
    t_img = np.arange(n) * 0.10375
    # synced packets: raw 100 Hz OXTS samples nearest to each frame
    t_pkt = np.round(t_img * 100) / 100 + 0.0036
    packets, _ = make_packets(t_pkt)
    file_t = t_pkt
    (drive / "image_02" / "timestamps.txt").write_text("".join(_stamp(t) + "\n" for t in t_img))
    (drive / "oxts" / "timestamps.txt").write_text("".join(_stamp(t) + "\n" for t in file_t))
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(drive / "image_02" / "data" / f"{i:010d}.png"), rng.integers(0, 255, (H, W, 3), np.uint8))
        (drive / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(f"{v:.10f}" for v in packets[i]) + "\n")
        if bins:
            # a wall 10 m ahead of the velodyne (x forward), 20 m wide, 6 m high
            yy, zz = np.meshgrid(np.linspace(-10, 10, 400), np.linspace(-3, 3, 120))
            pts = np.stack([np.full(yy.size, 10.0), yy.ravel(), zz.ravel(), np.ones(yy.size)], 1).astype(np.float32)
            pts.tofile(drive / "velodyne_points" / "data" / f"{i:010d}.bin")
    _, true_xyz = make_packets(t_img)
    return drive, t_img, true_xyz


def test_calibration_chain(tmp_path):
    drive, _, _ = write_drive(tmp_path)
    calib = load_kitti_calibration(drive.parent, camera=2)
    assert calib.camera == Camera(W, H, 60.0, 60.0, 39.5, 14.5)
    # P_rect_02 translation: 3.0 / 60 = 0.05 m along x of the rectified camera
    T_c_velo = calib.T_c_velo
    np.testing.assert_allclose(T_c_velo[:3, 3], [0.05, -0.1, -0.3], atol=1e-12)
    # a point 10 m ahead of the velodyne is 10 m ahead of the camera (z) and above it is up (-y)
    p = T_c_velo[:3, :3] @ [10.0, 0.0, 1.0] + T_c_velo[:3, 3]
    np.testing.assert_allclose(p, [0.05, -1.1, 9.7], atol=1e-12)
    np.testing.assert_allclose(calib.T_c_i, T_c_velo @ calib.T_velo_i)


def test_oxts_poses_recover_the_trajectory():
    t = np.linspace(0, 2, 21)
    packets, xyz = make_packets(t)
    T = oxts_poses(packets)
    np.testing.assert_allclose(T[:, :3, 3], xyz - xyz[0], atol=2e-3)  # Mercator is exact up to mm here
    R = Rotation.from_euler("ZYX", packets[:, [F["yaw"], F["pitch"], F["roll"]]]).as_matrix()
    np.testing.assert_allclose(T[:, :3, :3], R, atol=1e-12)
    # roll/pitch/yaw convention: the car's x axis (forward) points along the velocity
    fwd = T[:, :3, 0]
    vel = packets[:, [F["ve"], F["vn"]]]
    cos = np.sum(fwd[:, :2] * vel, 1) / np.linalg.norm(fwd[:, :2], axis=1) / np.linalg.norm(vel, axis=1)
    assert cos.min() > 0.9999


def test_retime_recovers_packet_offsets():
    t_img = np.arange(12) * 0.10375 + 0.002
    t_pkt = np.round(t_img * 100) / 100  # nearest raw 100 Hz tick of each frame
    packets, _ = make_packets(t_pkt)
    T = oxts_poses(packets)
    v = packets[:, [F["ve"], F["vn"], F["vu"]]]
    est = retime_oxts_packets(T, v, t_img)
    # known up to a constant: the packet-minus-image offsets are centred
    true_off = t_pkt - t_img
    np.testing.assert_allclose(est - t_img, true_off - 0.5 * (true_off.max() + true_off.min()), atol=2e-4)


def test_open_synthetic_drive(tmp_path):
    drive, t_img, xyz = write_drive(tmp_path)
    for path in (tmp_path, drive.parent, drive):  # root, date folder or drive folder
        seq = open_sequence(path)
        assert isinstance(seq, KittiRawSequence) and len(seq) == 5
    seq = open_sequence(tmp_path, format="kitti_raw")
    f = seq[3]
    assert f.stem == "0000000003" and f.image().shape == (H, W, 3)
    assert f.timestamp - seq[0].timestamp == pytest.approx(3 * 0.10375, abs=1e-6)
    # poses at the image times: IMU displacement along the true trajectory
    p0, p3 = [(seq[i].T_w_c @ seq.imu.T_c_i)[:3, 3] for i in (0, 3)]
    np.testing.assert_allclose(p3 - p0, xyz[3] - xyz[0], atol=0.01)
    # velocity = (ve, vn, vu), tangent to the trajectory
    np.testing.assert_allclose(f.velocity_w, seq.packets[3, [F["ve"], F["vn"], F["vu"]]])
    chord = xyz[4] - xyz[2]
    assert np.dot(chord, f.velocity_w) / np.linalg.norm(chord) / np.linalg.norm(f.velocity_w) > 0.9999
    imu = seq.imu
    assert imu.accel.shape == (5, 3) and imu.accel[0, 2] == pytest.approx(9.81)
    assert imu.gyro[0, 2] == pytest.approx(0.05)
    np.testing.assert_allclose(imu.T_c_i, load_kitti_calibration(drive.parent).T_c_i)
    # ground truth from the velodyne scan: the wall is 10 m ahead of the velodyne = 9.7 m in the camera
    d = f.gt_depth()
    assert d.dtype == np.float32 and d.shape == (H, W)
    assert (d > 0).mean() > 0.3
    np.testing.assert_allclose(d[d > 0], 9.7, atol=1e-5)


def test_project_velodyne_keeps_nearest_and_drops_behind(tmp_path):
    cam = Camera(W, H, 60.0, 60.0, 39.5, 14.5)
    T = np.eye(4)  # points already in camera axes
    pts = np.array([[0.0, 0.0, 10.0, 1], [0.0, 0.0, 5.0, 1], [0.0, 0.0, 20.0, 1],
                    [0.0, 0.0, -5.0, 1], [100.0, 0.0, 1.0, 1]], np.float32)
    path = tmp_path / "scan.bin"
    pts.tofile(path)
    d = project_velodyne(read_velodyne_bin(path), T, cam)
    assert d[14, 40] == pytest.approx(5.0)  # pixel (39.5, 14.5) rounds to (40, 14): nearest of 5/10/20
    assert (d > 0).sum() == 1  # behind-camera and out-of-image points dropped
    path.write_bytes(b"\0" * 20)
    with pytest.raises(SequenceFormatError, match="scan.bin"):
        read_velodyne_bin(path)


def test_devkit_timing_option(tmp_path):
    drive, t_img, xyz = write_drive(tmp_path)
    plain = KittiRawSequence(drive, KittiSettings(retime_packets=False, poses_at_image_time=False))
    default = KittiRawSequence(drive)
    # plain recipe: pose k is packet k, i.e. the trajectory at the packet time
    t_pkt = plain.packet_times
    _, xyz_pkt = make_packets(t_pkt - t_pkt[0] + (round(t_img[0] * 100) / 100 + 0.0036))
    P = np.stack([(plain[i].T_w_c @ plain.imu.T_c_i)[:3, 3] for i in range(5)])
    np.testing.assert_allclose(P, xyz_pkt - xyz_pkt[0], atol=2e-3)
    # default: moved to the image times (relative motion between frames = true motion)
    Q = np.stack([(default[i].T_w_c @ default.imu.T_c_i)[:3, 3] for i in range(5)])
    np.testing.assert_allclose(np.diff(Q, axis=0), np.diff(xyz, axis=0), atol=3e-3)
    assert np.max(np.abs(np.diff(P, axis=0) - np.diff(xyz, axis=0))) > 0.02  # the plain recipe is off


def test_malformed_files_name_the_file(tmp_path):
    drive, _, _ = write_drive(tmp_path / "a")
    packet = drive / "oxts" / "data" / "0000000002.txt"
    packet.write_text(" ".join(packet.read_text().split()[:17]) + "\n")  # truncated line
    truncated = r"0000000002.txt:1: truncated OXTS packet: expected 30 values, got 17"
    with pytest.raises(SequenceFormatError, match=truncated):
        open_sequence(drive)

    drive, _, _ = write_drive(tmp_path / "b")
    cc = drive.parent / "calib_cam_to_cam.txt"
    cc.write_text("\n".join(ln for ln in CAM_TO_CAM.splitlines() if not ln.startswith("P_rect_02")))
    with pytest.raises(SequenceFormatError, match=r"calib_cam_to_cam.txt: missing calibration key 'P_rect_02'"):
        open_sequence(drive)

    drive, _, _ = write_drive(tmp_path / "c")
    (drive.parent / "calib_velo_to_cam.txt").unlink()
    with pytest.raises(SequenceFormatError, match=r"calib_velo_to_cam.txt: calibration file not found"):
        KittiRawSequence(drive)

    drive, _, _ = write_drive(tmp_path / "d")
    ts = drive / "image_02" / "timestamps.txt"
    lines = ts.read_text().splitlines()
    lines[2] = "2011-09-26 13:17:xx"
    ts.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match=r"image_02/timestamps.txt:3"):
        KittiRawSequence(drive)

    drive, _, _ = write_drive(tmp_path / "e")
    (drive / "oxts" / "data" / "0000000004.txt").unlink()
    with pytest.raises(SequenceFormatError, match=r"no OXTS packet for images: 0000000004.txt"):
        KittiRawSequence(drive)

    with pytest.raises(InputError, match="not a KITTI raw drive"):
        KittiRawSequence(tmp_path / "a" / "2011_09_26" / "2011_09_26_drive_0001_sync" / "image_02")


def _lidar_reprojection_error(fa, fb):
    """Median relative error of frame a's LiDAR depth moved into frame b with the poses."""
    err = depth_reprojection_errors(fa.gt_depth(), fb.gt_depth(), fa.camera, relative_transform(fb.T_w_c, fa.T_w_c))
    return float(np.median(err)), len(err)


@pytest.mark.shared_data
def test_kitti_tiny_oxts_poses_reproject_lidar_depth():
    if not DATA.is_dir():
        pytest.skip(f"{DATA} not present")
    seq = open_sequence(DATA)
    assert isinstance(seq, KittiRawSequence) and len(seq) == 7
    assert seq.camera.fx == pytest.approx(721.5377)
    frames = [seq[i] for i in range(len(seq))]
    results = [_lidar_reprojection_error(frames[k], frames[k + 1]) for k in range(len(frames) - 1)]
    errors = [e for e, _ in results]
    # measured: 0.27-0.89 % (median 0.46 %) for the 6 one-frame pairs
    assert all(n > 500 for _, n in results)
    assert max(errors) < 0.02, errors
    # the OXTS velocity agrees with the pose increments (8.8 m/s, frames 0.104 s apart)
    step = np.linalg.norm(frames[1].T_w_c[:3, 3] - frames[0].T_w_c[:3, 3])
    speed = np.linalg.norm(frames[0].velocity_w)
    assert step == pytest.approx(speed * (frames[1].timestamp - frames[0].timestamp), rel=0.05)
