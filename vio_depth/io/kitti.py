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

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import invert_transform
from vio_core.npyfile import load_array

from ..frame import Frame, ImuData, imu_sample_problem
from .base import Sequence, SequenceFormat
from .images import read_rgb_image
from .kitti_oxts import (
    CALIB_CAM_TO_CAM,
    load_kitti_calibration,
    oxts_imu_samples,
    oxts_poses,
    oxts_velocity_w,
    project_velodyne,
    read_kitti_timestamps,
    read_oxts_packet,
    read_velodyne_bin,
    retime_oxts_packets,
    shift_poses_in_time,
)


def _load_npz_depth(path: Path, camera: Camera | None = None) -> np.ndarray:
    d = load_array(path, "projected depth", key="velodyne_depth")
    if d.ndim != 2 or d.dtype.kind not in "fiu" or (
            camera is not None and d.shape != (camera.height, camera.width)):
        want = "" if camera is None else f" ({camera.height}, {camera.width})"
        raise SequenceFormatError(path, f"projected depth must be a 2-D number array{want}, got {d.dtype} {d.shape}")
    d = d.astype(np.float32)
    return np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32)


def _load_bin_depth(path: Path, T_c_velo: np.ndarray, camera: Camera) -> np.ndarray:
    return project_velodyne(read_velodyne_bin(path), T_c_velo, camera)


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
    pose_kind = "ins"

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
        problem = imu_sample_problem(gyro_all, accel_all)
        if problem is not None:
            raise SequenceFormatError(packet_files[problem[0]], problem[1])
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
            return partial(_load_npz_depth, npz, self.camera)
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


FORMAT = SequenceFormat(
    "kitti_raw", _detect, KittiRawSequence,
    "KITTI raw drive (image_02 + OXTS poses/IMU + velodyne or proj_depth ground truth)",
)
