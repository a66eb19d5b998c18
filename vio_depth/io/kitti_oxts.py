"""KITTI raw calibration, timestamps and OXTS packets: readers and the pose recipe.

The sequence built from them is :class:`vio_depth.io.kitti.KittiRawSequence` (see its module).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SequenceFormatError

from .rasterize import rasterize_depth
from .tables import read_text_table

#: Number of values in one OXTS packet (see ``oxts/dataformat.txt``).
OXTS_FIELDS = (
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu",
    "ax", "ay", "az", "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu",
    "pos_accuracy", "vel_accuracy", "navstat", "numsats", "posmode", "velmode", "orimode",
)
_F = {name: i for i, name in enumerate(OXTS_FIELDS)}
EARTH_RADIUS_M = 6378137.0
#: OXTS positions beyond these are refused (the Mercator projection diverges at the poles;
#: no vehicle drives 100 km above or below sea level)
MAX_LATITUDE_DEG = 85.0
MAX_ALTITUDE_M = 1e5

CALIB_CAM_TO_CAM = "calib_cam_to_cam.txt"
CALIB_IMU_TO_VELO = "calib_imu_to_velo.txt"
CALIB_VELO_TO_CAM = "calib_velo_to_cam.txt"


# --------------------------------------------------------------------------- files
def read_calib_file(path) -> dict[str, np.ndarray]:
    """Read a KITTI ``key: v1 v2 ...`` calibration file into ``{key: (n,) float64}``.

    Lines whose values are not all numbers (``calib_time: 09-Jan-2012 ...``) are kept
    out. Raises :class:`SequenceFormatError` (file and line) for a line without ``:``.
    """
    table = read_text_table(path, "calibration", layout="key: values", min_columns=1)
    out: dict[str, np.ndarray] = {}
    for i, fields in enumerate(table.rows):
        key, sep, rest = " ".join(fields).partition(":")
        if not sep:
            raise table.error(i, f"expected 'key: values', got {' '.join(fields)[:40]!r}")
        try:
            out[key.strip()] = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            continue  # e.g. calib_time
    return out


def _calib_value(calib: dict, path: Path, key: str, size: int) -> np.ndarray:
    if key not in calib:
        raise SequenceFormatError(path, f"missing calibration key {key!r}")
    v = calib[key]
    if v.size != size:
        raise SequenceFormatError(path, f"calibration key {key!r} has {v.size} values, expected {size}")
    return v


def read_kitti_timestamps(path) -> np.ndarray:
    """``timestamps.txt`` (``YYYY-MM-DD HH:MM:SS.fffffffff`` per line) -> (N,) float64 seconds.

    Seconds since the POSIX epoch, reading the (local) clock of the file as if it were
    UTC; only differences matter. Raises :class:`SequenceFormatError` naming file and line.
    """
    table = read_text_table(path, "timestamp", layout="YYYY-MM-DD HH:MM:SS.fff", columns=2)
    out = []
    for i, (day, clock) in enumerate(table.rows):
        try:
            hms, _, frac = clock.partition(".")
            base = _dt.datetime.strptime(f"{day} {hms}", "%Y-%m-%d %H:%M:%S").replace(tzinfo=_dt.timezone.utc)
            out.append(base.timestamp() + (float("0." + frac) if frac else 0.0))
        except ValueError:
            raise table.error(i, f"expected 'YYYY-MM-DD HH:MM:SS.fff', got {day + ' ' + clock!r}") from None
    return np.asarray(out, dtype=np.float64)


def read_oxts_packet(path) -> np.ndarray:
    """One OXTS packet file -> (30,) float64 (fields in :data:`OXTS_FIELDS` order).

    Raises :class:`SequenceFormatError` naming the file for a truncated or non-numeric line.
    """
    table = read_text_table(path, "OXTS packet", allow_empty=True)
    if len(table) != 1:
        raise table.error(None, f"expected one OXTS line, found {len(table)}")
    if len(table.rows[0]) != len(OXTS_FIELDS):
        raise table.error(0, f"truncated OXTS packet: expected {len(OXTS_FIELDS)} values, got {len(table.rows[0])}")
    values = table.floats(what="OXTS value")[0]
    lat, lon, alt = values[_F["lat"]], values[_F["lon"]], values[_F["alt"]]
    if not (abs(lat) <= MAX_LATITUDE_DEG and abs(lon) <= 180.0 and abs(alt) <= MAX_ALTITUDE_M):
        raise table.error(0, f"lat {lat:.6g} deg, lon {lon:.6g} deg, alt {alt:.6g} m is not a place on Earth "
                             f"(|lat| <= {MAX_LATITUDE_DEG:g}, |lon| <= 180, |alt| <= {MAX_ALTITUDE_M:g} m)")
    return values


def read_velodyne_bin(path) -> np.ndarray:
    """A ``velodyne_points/data/*.bin`` scan -> (N, 4) float32 (x, y, z metres, reflectance)."""
    path = Path(path)
    raw = np.fromfile(path, dtype=np.float32)
    if raw.size % 4:
        raise SequenceFormatError(path, f"velodyne scan size {raw.size * 4} bytes is not a multiple of 16")
    return raw.reshape(-1, 4)


# --------------------------------------------------------------------------- calibration
@dataclass(frozen=True)
class KittiCalibration:
    """Rectified camera and extrinsics of one KITTI camera.

    Attributes:
        camera: rectified pinhole camera (from ``P_rect_0x`` and ``S_rect_0x``).
        T_c_velo: (4, 4) velodyne-to-camera transform (rectified camera frame), metres.
        T_velo_i: (4, 4) IMU(OXTS)-to-velodyne transform, metres.
        P_rect: (3, 4) rectified projection matrix of this camera.
    """

    camera: Camera
    T_c_velo: np.ndarray
    T_velo_i: np.ndarray
    P_rect: np.ndarray

    @property
    def T_c_i(self) -> np.ndarray:
        """(4, 4) IMU-to-camera transform."""
        return self.T_c_velo @ self.T_velo_i


def _rigid(R_flat: np.ndarray, t: np.ndarray, path, key: str) -> np.ndarray:
    R = R_flat.reshape(3, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        off = float(np.abs(R @ R.T - np.eye(3)).max())
    if not (off <= 1e-3 and np.all(np.abs(t) <= 1e3)):  # a camera rig is not kilometres wide
        raise SequenceFormatError(path, f"{key} is not a rigid calibration (rotation off by {off:.3g}, "
                                        f"translation {np.asarray(t).tolist()} m)")
    # calibration rotations are printed with 7 digits: re-orthonormalise
    U, _, Vt = np.linalg.svd(R)
    T = np.eye(4)
    T[:3, :3] = U @ Vt
    T[:3, 3] = t
    return T


def load_kitti_calibration(calib_dir, camera: int = 2) -> KittiCalibration:
    """Read the three calibration files in ``calib_dir`` for camera ``camera`` (0-3).

    Raises:
        SequenceFormatError: a file or key is missing or malformed (names the file).
    """
    calib_dir = Path(calib_dir)
    if camera not in (0, 1, 2, 3):
        raise InputError(f"KITTI camera index must be 0..3, got {camera}")
    p_cc = calib_dir / CALIB_CAM_TO_CAM
    p_iv = calib_dir / CALIB_IMU_TO_VELO
    p_vc = calib_dir / CALIB_VELO_TO_CAM
    cc, iv, vc = read_calib_file(p_cc), read_calib_file(p_iv), read_calib_file(p_vc)

    P = _calib_value(cc, p_cc, f"P_rect_{camera:02d}", 12).reshape(3, 4)
    size = _calib_value(cc, p_cc, f"S_rect_{camera:02d}", 2)
    R_rect = np.eye(4)
    R_rect[:3, :3] = _rigid(_calib_value(cc, p_cc, "R_rect_00", 9), np.zeros(3), p_cc, "R_rect_00")[:3, :3]
    K = P[:, :3]
    # P = K [I | t]: the translation of this rectified camera from rectified camera 0
    T_c_c0 = np.eye(4)
    T_c_c0[:3, 3] = np.linalg.solve(K, P[:, 3])
    T_velo_to_cam0 = _rigid(_calib_value(vc, p_vc, "R", 9), _calib_value(vc, p_vc, "T", 3), p_vc, "R, T")
    T_velo_i = _rigid(_calib_value(iv, p_iv, "R", 9), _calib_value(iv, p_iv, "T", 3), p_iv, "R, T")
    cam = Camera.from_K(K, int(round(size[0])), int(round(size[1])))
    return KittiCalibration(cam, T_c_c0 @ R_rect @ T_velo_to_cam0, T_velo_i, P)


# --------------------------------------------------------------------------- OXTS maths
def oxts_poses(packets) -> np.ndarray:
    """IMU-to-world poses from OXTS packets with the standard KITTI recipe.

    Args:
        packets: (N, 30) OXTS values (:data:`OXTS_FIELDS`), lat/lon in degrees, alt in
            metres, roll/pitch/yaw in radians.

    Returns:
        T_w_i: (N, 4, 4) IMU-to-world, metres. World: x east, y north, z up (Mercator,
        scale ``cos(lat_0)``), origin at the first packet, gravity along -z.
    """
    p = check_array("packets", packets, (None, len(OXTS_FIELDS)), finite=True)
    scale = np.cos(np.radians(p[0, _F["lat"]]))
    tx = scale * np.radians(p[:, _F["lon"]]) * EARTH_RADIUS_M
    ty = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + p[:, _F["lat"]]) / 2.0))
    t = np.stack([tx, ty, p[:, _F["alt"]]], axis=1)
    R = Rotation.from_euler("ZYX", p[:, [_F["yaw"], _F["pitch"], _F["roll"]]]).as_matrix()  # Rz Ry Rx
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = t - t[0]
    return T


def oxts_velocity_w(packets) -> np.ndarray:
    """(N, 3) m/s IMU velocity in the :func:`oxts_poses` world frame (east, north, up)."""
    p = check_array("packets", packets, (None, len(OXTS_FIELDS)), finite=True)
    return p[:, [_F["ve"], _F["vn"], _F["vu"]]].copy()


def oxts_imu_samples(packets) -> tuple[np.ndarray, np.ndarray]:
    """IMU-frame samples from OXTS packets ``(N, 30)``.

    Returns:
        gyro: (N, 3) rad/s (``wx, wy, wz``); accel: (N, 3) m/s^2 specific force
        (``ax, ay, az``, gravity included, the convention of :class:`~vio_depth.frame.ImuData`).
    """
    p = check_array("packets", packets, (None, len(OXTS_FIELDS)), finite=True)
    return p[:, [_F["wx"], _F["wy"], _F["wz"]]].copy(), p[:, [_F["ax"], _F["ay"], _F["az"]]].copy()


def shift_poses_in_time(T_w_i, velocity_w, gyro, dt) -> np.ndarray:
    """Move IMU poses by ``dt`` seconds at constant velocity and body rate.

    Args:
        T_w_i: (N, 4, 4) IMU-to-world poses, metres.
        velocity_w: (N, 3) m/s world-frame velocity.
        gyro: (N, 3) rad/s body angular rate.
        dt: (N,) seconds (target time minus pose time).

    Returns:
        (N, 4, 4) IMU-to-world poses at the target times.
    """
    T = check_array("T_w_i", T_w_i, (None, 4, 4), finite=True)
    n = len(T)
    v = check_array("velocity_w", velocity_w, (n, 3), finite=True)
    w = check_array("gyro", gyro, (n, 3), finite=True)
    dt = check_array("dt", dt, (n,), finite=True)
    out = T.copy()
    out[:, :3, 3] += v * dt[:, None]
    out[:, :3, :3] = T[:, :3, :3] @ Rotation.from_rotvec(w * dt[:, None]).as_matrix()
    return out


def project_velodyne(points_velo, T_c_velo, camera: Camera, *, min_depth: float = 0.1) -> np.ndarray:
    """Project a LiDAR scan into a sparse depth image, keeping the nearest point per pixel.

    Args:
        points_velo: (N, 3) metres in the velodyne frame (extra columns, e.g. the
            reflectance of a (N, 4) scan, are ignored).
        T_c_velo: (4, 4) velodyne-to-camera transform (rectified camera frame).
        camera: pinhole camera of the (rectified, undistorted) image.
        min_depth: metres; points nearer than this are dropped.

    Returns:
        (H, W) float32 depth in metres (camera z), 0 = no point.
    """
    pts = check_array("points_velo", points_velo, (None, None))
    if pts.shape[1] < 3:
        raise InputError(f"points_velo: expected at least 3 columns, got {pts.shape[1]}")
    T = check_transform("T_c_velo", T_c_velo)
    p_c = pts[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    return rasterize_depth(p_c[p_c[:, 2] > min_depth], camera)


# --------------------------------------------------------------------------- timing
#: tick of the raw OXTS stream (100 Hz) from which the sync data picked its packets, seconds
OXTS_TICK_S = 0.01


def retime_oxts_packets(T_w_i, velocity_w, image_times, *, tick_s: float = OXTS_TICK_S,
                        min_speed: float = 2.0) -> np.ndarray:
    """Times of synced OXTS packets on the image clock, from the packets' own motion.

    In the ``*_sync`` drives every frame carries the raw 100 Hz OXTS packet nearest to it,
    so consecutive packets are a whole number of 10 ms ticks apart (10 or 11 at the
    10.4 Hz frame rate) and each packet lies within about +-5 ms of its frame. The tick
    count of each interval is read from the packets themselves: the position increment
    along the mean velocity divided by the speed, rounded to whole ticks (below
    ``min_speed`` the nominal count ``round(image interval / tick)`` is used instead).
    The constant offset is chosen to centre the packet-minus-image offsets.
    ``oxts/timestamps.txt`` is not used: on drive 2011_09_26_0023 its intervals
    (10, 11, 10, 11, 10, 10 ticks) do not match the packets' motion (11, 10, 11, 10, 10,
    11 ticks), which shows up as +-5 % alternating errors of 1-frame triangulations.

    Args:
        T_w_i: (N, 4, 4) IMU-to-world poses of consecutive packets, metres.
        velocity_w: (N, 3) m/s world-frame velocity of each packet.
        image_times: (N,) seconds, timestamp of the frame each packet belongs to.
        tick_s: raw OXTS sample period, seconds.
        min_speed: m/s; slower intervals use the nominal tick count.

    Returns:
        (N,) seconds, packet times on the image clock.
    """
    T = check_array("T_w_i", T_w_i, (None, 4, 4), finite=True)
    n = len(T)
    v = check_array("velocity_w", velocity_w, (n, 3), finite=True)
    t_img = check_array("image_times", image_times, (n,), finite=True)
    if n == 1:
        return t_img.copy()
    dp = np.diff(T[:, :3, 3], axis=0)
    v_mid = 0.5 * (v[1:] + v[:-1])
    speed2 = np.sum(v_mid * v_mid, axis=1)
    moving = speed2 >= min_speed**2
    dt_motion = np.sum(dp * v_mid, axis=1) / np.where(moving, speed2, 1.0)
    dt = np.where(moving, dt_motion, np.diff(t_img))
    ticks = np.maximum(np.round(dt / tick_s), 1.0)
    t_packet = np.concatenate([[0.0], np.cumsum(ticks) * tick_s])
    offset = t_img - t_packet
    return t_packet + 0.5 * (offset.max() + offset.min())


# --------------------------------------------------------------------------- sequence
