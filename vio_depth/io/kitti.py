"""KITTI raw drive folders (the official ``<date>/<date>_drive_XXXX_sync`` layout).

What is read (see docs/datasets.md):

* images: ``image_02/data/*.png`` (left colour camera; ``camera=3`` selects the right one),
  timestamps from ``image_02/timestamps.txt`` (one line per frame number of the *whole*
  drive; line ``k`` belongs to ``data/<k:010d>.png``).
* intrinsics: the rectified ``P_rect_02`` from ``calib_cam_to_cam.txt`` (no distortion:
  the sync images are rectified).
* poses: OXTS packets ``oxts/data/*.txt`` with the standard KITTI recipe -- Mercator
  projection of lat/lon scaled by the first packet's latitude, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)``, translation relative to the first packet -- giving ``T_w_i`` (IMU to world,
  world = east/north/up at the first packet, gravity -z). The camera pose is
  ``T_w_c = T_w_i T_i_c`` with ``T_c_i = T_c_c0 R_rect_00 T_velo_to_cam T_imu_to_velo``
  (``T_c_c0`` is the translation of ``P_rect_0x``).
  By default the packets are timed on the image clock from their own motion
  (:func:`retime_oxts_packets`; ``oxts/timestamps.txt`` does not match the packets) and
  each pose is moved from its packet time to its image timestamp with the packet's
  velocity and angular rate (at most ~5 ms); see :class:`KittiSettings`.
* velocity: ``vn, ve, vu`` as the world-frame (east, north, up) IMU velocity.
* IMU: ``ax, ay, az`` (specific force in the vehicle/IMU frame, gravity included: a level
  car at rest reads ``az = +9.81``) and ``wx, wy, wz`` at the OXTS rate (10 Hz in the
  sync data, which is coarse). ``af, al, au`` / ``wf, wl, wu`` are *not* used: they are
  expressed in a yaw-only, earth-levelled frame, not in the IMU frame.
* ground-truth depth: ``proj_depth/velodyne/image_02/<stem>.npz`` (key
  ``velodyne_depth``) when present, else ``velodyne_points/data/<stem>.bin`` projected
  into the image (:func:`project_velodyne`), else none.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import invert_transform
from ..types import Frame, ImuData
from .base import Sequence, SequenceFormat, register_format
from .native import read_rgb_image
from .sevenscenes import rasterize_depth

#: Number of values in one OXTS packet (see ``oxts/dataformat.txt``).
OXTS_FIELDS = (
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu",
    "ax", "ay", "az", "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu",
    "pos_accuracy", "vel_accuracy", "navstat", "numsats", "posmode", "velmode", "orimode",
)
_F = {name: i for i, name in enumerate(OXTS_FIELDS)}
EARTH_RADIUS_M = 6378137.0

CALIB_CAM_TO_CAM = "calib_cam_to_cam.txt"
CALIB_IMU_TO_VELO = "calib_imu_to_velo.txt"
CALIB_VELO_TO_CAM = "calib_velo_to_cam.txt"


# --------------------------------------------------------------------------- files
def read_calib_file(path) -> dict[str, np.ndarray]:
    """Read a KITTI ``key: v1 v2 ...`` calibration file into ``{key: (n,) float64}``.

    Lines whose values are not all numbers (``calib_time: 09-Jan-2012 ...``) are kept
    out. Raises :class:`SequenceFormatError` (file and line) for a line without ``:``.
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "calibration file not found")
    out: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            raise SequenceFormatError(path, f"expected 'key: values', got {line.strip()[:40]!r}", lineno)
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
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "timestamp file not found")
    out = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s:
            continue
        try:
            day, clock = s.split()
            hms, _, frac = clock.partition(".")
            base = _dt.datetime.strptime(f"{day} {hms}", "%Y-%m-%d %H:%M:%S").replace(tzinfo=_dt.timezone.utc)
            out.append(base.timestamp() + (float("0." + frac) if frac else 0.0))
        except ValueError:
            raise SequenceFormatError(path, f"expected 'YYYY-MM-DD HH:MM:SS.fff', got {s[:40]!r}", lineno) from None
    return np.asarray(out, dtype=np.float64)


def read_oxts_packet(path) -> np.ndarray:
    """One OXTS packet file -> (30,) float64 (fields in :data:`OXTS_FIELDS` order).

    Raises :class:`SequenceFormatError` naming the file for a truncated or non-numeric line.
    """
    path = Path(path)
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    if len(lines) != 1:
        raise SequenceFormatError(path, f"expected one OXTS line, found {len(lines)}")
    parts = lines[0].split()
    if len(parts) != len(OXTS_FIELDS):
        raise SequenceFormatError(
            path, f"truncated OXTS packet: expected {len(OXTS_FIELDS)} values, got {len(parts)}", 1)
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise SequenceFormatError(path, "OXTS packet has a non-numeric value", 1) from None
    if not np.all(np.isfinite(values)):
        raise SequenceFormatError(path, "OXTS packet has a non-finite value", 1)
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


def _rigid(R_flat: np.ndarray, t: np.ndarray) -> np.ndarray:
    R = R_flat.reshape(3, 3)
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
    R_rect[:3, :3] = _rigid(_calib_value(cc, p_cc, "R_rect_00", 9), np.zeros(3))[:3, :3]
    K = P[:, :3]
    # P = K [I | t]: the translation of this rectified camera from rectified camera 0
    T_c_c0 = np.eye(4)
    T_c_c0[:3, 3] = np.linalg.solve(K, P[:, 3])
    T_velo_to_cam0 = _rigid(_calib_value(vc, p_vc, "R", 9), _calib_value(vc, p_vc, "T", 3))
    T_velo_i = _rigid(_calib_value(iv, p_iv, "R", 9), _calib_value(iv, p_iv, "T", 3))
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
        (``ax, ay, az``, gravity included, the convention of :class:`~vio_depth.types.ImuData`).
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


def _load_npz_depth(path: Path) -> np.ndarray:
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as z:
            if "velodyne_depth" not in z.files:
                raise SequenceFormatError(path, f"expected key 'velodyne_depth', found {z.files}")
            d = np.asarray(z["velodyne_depth"], dtype=np.float32)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise SequenceFormatError(path, f"cannot read projected depth: {exc}") from None
    return np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32)


def _load_bin_depth(path: Path, T_c_velo: np.ndarray, camera: Camera) -> np.ndarray:
    return project_velodyne(read_velodyne_bin(path), T_c_velo, camera)


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
@dataclass(frozen=True)
class KittiSettings:
    """Options of the KITTI raw loader.

    Attributes:
        camera: KITTI camera index, 2 = left colour (default), 3 = right colour.
        retime_packets: time the OXTS packets from their own motion
            (:func:`retime_oxts_packets`, default) instead of ``oxts/timestamps.txt``.
        poses_at_image_time: move each OXTS pose from its packet time to the image
            timestamp with the packet's velocity and angular rate (default True; a few
            milliseconds, i.e. a few centimetres). With both options False the poses are
            the plain per-index recipe of the KITTI devkit.
    """

    camera: int = 2
    retime_packets: bool = True
    poses_at_image_time: bool = True


def find_kitti_drive(path) -> Path | None:
    """The drive folder at or below ``path`` (itself, ``<date>/<drive>``, or ``<root>/<date>/<drive>``).

    Returns None when there is none. Raises :class:`InputError` listing them when
    there are several.
    """
    path = Path(path)
    if not path.is_dir():
        return None

    def is_drive(p: Path) -> bool:
        return (p / "oxts" / "data").is_dir() and any((p / f"image_0{c}" / "data").is_dir() for c in range(4))

    if is_drive(path):
        return path
    found = [p for p in sorted(path.glob("*")) if p.is_dir() and is_drive(p)]
    if not found:
        found = [p for p in sorted(path.glob("*/*")) if p.is_dir() and is_drive(p)]
    if len(found) > 1:
        raise InputError(f"{path}: several KITTI drives found; open one of: " + ", ".join(str(p) for p in found))
    return found[0] if found else None


def _frame_number(p: Path) -> int:
    try:
        return int(p.stem)
    except ValueError:
        raise SequenceFormatError(p, "KITTI file names must be frame numbers like 0000000042") from None


def _lines_for(times: np.ndarray, numbers: np.ndarray, path: Path) -> np.ndarray:
    if numbers.max() >= len(times):
        raise SequenceFormatError(
            path, f"{len(times)} timestamp lines, but frame {numbers.max()} needs line {numbers.max() + 1}")
    return times[numbers]


class KittiRawSequence(Sequence):
    """A KITTI raw ``*_sync`` drive: rectified left colour images, OXTS poses and IMU, LiDAR depth.

    Args:
        path: the drive folder (``.../2011_09_26/2011_09_26_drive_0023_sync``), its date
            folder, or a folder holding one date folder. Calibration files are read from
            the drive's parent (official layout) or from the drive folder itself.
        settings: see :class:`KittiSettings`.

    Attributes:
        packet_times: (M,) seconds, times of all OXTS packets of the drive (image clock).
        packets: (M, 30) the OXTS packets.
    """

    format_name = "kitti_raw"

    def __init__(self, path, settings: KittiSettings = KittiSettings()):
        drive = find_kitti_drive(path)
        if drive is None:
            raise InputError(f"{path}: not a KITTI raw drive folder (no oxts/data and image_0x/data)")
        self.settings = settings
        self.drive = drive
        calib_dir = drive.parent if (drive.parent / CALIB_CAM_TO_CAM).is_file() else drive
        self.calibration = load_kitti_calibration(calib_dir, settings.camera)
        cam_dir = drive / f"image_{settings.camera:02d}"
        images = sorted((cam_dir / "data").glob("*.png"))
        if not images:
            raise InputError(f"{cam_dir / 'data'}: no .png images")
        self._images = images
        numbers = np.array([_frame_number(p) for p in images])
        image_times_all = read_kitti_timestamps(cam_dir / "timestamps.txt")
        self._times = _lines_for(image_times_all, numbers, cam_dir / "timestamps.txt")

        # every OXTS packet of the drive (IMU samples); the images need theirs
        oxts_dir = drive / "oxts"
        packet_files = sorted((oxts_dir / "data").glob("*.txt"))
        packet_numbers = np.array([_frame_number(p) for p in packet_files], dtype=np.int64)
        missing = sorted(set(numbers.tolist()) - set(packet_numbers.tolist()))
        if missing:
            raise SequenceFormatError(oxts_dir / "data", "no OXTS packet for images: "
                                      + ", ".join(f"{n:010d}.txt" for n in missing[:5]))
        self.packets = np.stack([read_oxts_packet(p) for p in packet_files])
        T_w_i_all = oxts_poses(self.packets)
        velocity_all = oxts_velocity_w(self.packets)
        gyro_all, accel_all = oxts_imu_samples(self.packets)
        if settings.retime_packets:
            contiguous = np.all(np.diff(packet_numbers) == 1)
            if not contiguous:
                raise SequenceFormatError(oxts_dir / "data", "OXTS packets are not consecutive frame numbers; "
                                          "open with KittiSettings(retime_packets=False)")
            self.packet_times = retime_oxts_packets(
                T_w_i_all, velocity_all, _lines_for(image_times_all, packet_numbers, cam_dir / "timestamps.txt"))
        else:
            ts_path = oxts_dir / "timestamps.txt"
            self.packet_times = _lines_for(read_kitti_timestamps(ts_path), packet_numbers, ts_path)
            if np.any(np.diff(self.packet_times) <= 0):
                raise SequenceFormatError(ts_path, "OXTS timestamps are not strictly increasing")

        row = np.searchsorted(packet_numbers, numbers)
        T_w_i = T_w_i_all[row]
        if settings.poses_at_image_time:
            T_w_i = shift_poses_in_time(T_w_i, velocity_all[row], gyro_all[row], self._times - self.packet_times[row])
        T_c_i = self.calibration.T_c_i
        self._T_w_c = T_w_i @ invert_transform(T_c_i)
        self._velocity = velocity_all[row]
        # OXTS RT3003-class unit; the noise densities are nominal (see docs/datasets.md)
        imu = ImuData(self.packet_times.copy(), gyro_all, accel_all, T_c_i, gyro_noise=1.0e-3, accel_noise=2.0e-2,
                      gyro_bias_walk=1.0e-4, accel_bias_walk=1.0e-3, gravity_w=(0.0, 0.0, -9.81))

        cam_name = f"image_{settings.camera:02d}"
        self._npz_dir = drive / "proj_depth" / "velodyne" / cam_name
        self._bin_dir = drive / "velodyne_points" / "data"
        super().__init__(drive, drive.name, self.calibration.camera, imu)

    def __len__(self) -> int:
        return len(self._images)

    @property
    def has_gt_depth(self) -> bool:
        return self._npz_dir.is_dir() or self._bin_dir.is_dir()

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) image timestamps, seconds."""
        return self._times.copy()

    def _depth_loader(self, stem: str):
        npz = self._npz_dir / f"{stem}.npz"
        if npz.is_file():
            return partial(_load_npz_depth, npz)
        scan = self._bin_dir / f"{stem}.bin"
        if scan.is_file():
            return partial(_load_bin_depth, scan, self.calibration.T_c_velo, self.camera)
        return None

    def frame(self, index: int) -> Frame:
        path = self._images[index]
        return Frame(
            index=index,
            timestamp=float(self._times[index]),
            stem=path.stem,
            camera=self.camera,
            T_w_c=self._T_w_c[index].copy(),
            load_image=partial(read_rgb_image, path, self.camera),
            load_gt_depth=self._depth_loader(path.stem),
            velocity_w=self._velocity[index].copy(),
        )


def _detect(path: Path) -> bool:
    try:
        return find_kitti_drive(path) is not None
    except InputError:
        return True  # several drives: let open() say which


register_format(SequenceFormat(
    "kitti_raw", _detect, KittiRawSequence,
    "KITTI raw drive (image_02 + OXTS poses/IMU + velodyne or proj_depth ground truth)",
))
