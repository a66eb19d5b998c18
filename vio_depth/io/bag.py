"""ROS bags as sequences: ROS 1 ``.bag``, ROS 2 bag folders (SQLite3 or MCAP storage) and bare ``.mcap`` files.

Read through the pure-Python ``rosbags`` library (no ROS installation). Auto-detected as
format ``rosbag``; ``vio-depth run BAG --image-topic ... [--imu-topic ...]
[--camera-info-topic ...] [--pose-topic ...] [--calib camchain.yaml] [--imu-calib imu.yaml]``
(docs/ros.md).

**What is read.** Opening the bag streams through it once, in bag order, and keeps per
image only its header stamp, its bag (receive) time and its rank among messages with that
bag time (three integers); the IMU samples, the pose samples and the first ``CameraInfo``
are kept as arrays (small: 56 bytes per IMU sample). An image's pixels are read again from
the bag when the frame's ``image()`` is called (a time-indexed lookup: the ROS 1 index, the
SQLite3 timestamp, the MCAP chunk index), so memory does not grow with the bag's length
(benchmarks/bench_bag.py). Reads are serialised by a lock (the prefetch threads of a run
share the open bag); decoding runs outside it.

**Conventions.** Frames are named by their header stamp in nanoseconds (``stem =
str(stamp_ns)``, as in the ASL layout, so ``--disparity-dir`` files and every output name
match an ASL conversion of the same recording) and timed by it (``stamp_ns / 1e9`` s). The
camera comes from ``--calib`` (Kalibr) when given, else the ``CameraInfo`` topic. The IMU is
usable with a camera-IMU extrinsic (``T_cam_imu`` of ``--calib``) and a noise model
(``--imu-calib``); ``timeshift_cam_imu`` moves the IMU samples onto the camera clock. Poses
(``gt``) are the pose topic's frame in its world (z up, gravity ``-z``): the IMU's
(``pose_frame="imu"``, as EuRoC's ground truth, then ``T_w_c = T_w_i T_cam_imu^-1``) or the
camera's (``pose_frame="camera"``); each frame takes the pose interpolated between the two
samples bracketing its stamp when they are at most ``max_pose_gap_s`` apart.

**Refused with one line** (:class:`~vio_core.errors.InputError`): a missing, empty or
damaged bag, a missing or ambiguous topic (the candidates are listed), a topic of the wrong
type, an unsupported image encoding or camera model, header stamps that do not increase
or jump against the bag clock (``max_clock_jump_s``), images of another size than the camera.
"""

from __future__ import annotations

import logging
import threading
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import invert_transform

from ..frame import Frame, ImuData, imu_sample_problem
from .bag_messages import camera_from_info, check_image_encoding, image_from_message, imu_sample, pose_sample, stamp_ns
from .bag_topics import BagTopics, TopicChoice, choose_topics, open_reader, reader_error
from .base import Sequence, SequenceFormat
from .kalibr import Calibration, calibrated_imu
from .tables import QUATERNION_NORM_TOLERANCE, interpolate_poses

log = logging.getLogger(__name__)

#: pose frames a pose topic may describe
POSE_FRAMES = ("imu", "camera")
#: world gravity of bag poses (ROS REP 103: z up)
BAG_GRAVITY_W = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class BagSettings:
    """How a bag becomes a sequence.

    Attributes:
        image_topic / imu_topic / camera_info_topic / pose_topic: the topics; None picks the
            only topic of the right type (an image topic must then be unique; the others
            are optional), ``"none"`` uses none.
        pose_frame: what the poses describe, ``"imu"`` (EuRoC's ground truth) or ``"camera"``.
        calibration: Kalibr camera chain / IMU noise (:mod:`vio_depth.io.kalibr`).
        rectified: the images are rectified (``P``, no distortion, is then read from
            ``CameraInfo``); None: when the image topic's name contains ``rect``.
        max_pose_gap_s: seconds; a frame takes a pose only between two samples at most this far apart.
        max_clock_jump_s: seconds; the header stamp minus the bag time of consecutive
            messages of a topic may change by at most this much (else: a clock jump).
    """

    image_topic: str | None = None
    imu_topic: str | None = None
    camera_info_topic: str | None = None
    pose_topic: str | None = None
    pose_frame: str = "imu"
    calibration: Calibration = field(default_factory=Calibration)
    rectified: bool | None = None
    max_pose_gap_s: float = 0.1
    max_clock_jump_s: float = 1.0

    def __post_init__(self):
        if self.pose_frame not in POSE_FRAMES:
            raise SettingsError(f"pose frame {self.pose_frame!r}: expected one of {', '.join(POSE_FRAMES)}")
        for name in ("max_pose_gap_s", "max_clock_jump_s"):
            if not getattr(self, name) > 0:
                raise SettingsError(f"BagSettings.{name} must be positive, got {getattr(self, name)}")


class _Stamps:
    """Header stamps of one topic, checked as they arrive: strictly increasing, no clock jump."""

    def __init__(self, topic: str, max_jump_ns: int):
        self.topic, self.max_jump_ns = topic, max_jump_ns
        self.stamps = array("q")
        self._last_offset: int | None = None

    def add(self, stamp: int, bag_ns: int) -> None:
        n = len(self.stamps)
        if stamp <= 0:
            raise InputError(f"{self.topic}: message {n} has no header stamp (0); vio-depth times frames by "
                             "their header stamps")
        if n and stamp <= self.stamps[-1]:
            raise InputError(f"{self.topic}: header stamps do not increase at message {n} "
                             f"({stamp} ns after {self.stamps[-1]} ns)")
        offset = stamp - bag_ns
        if self._last_offset is not None and abs(offset - self._last_offset) > self.max_jump_ns:
            jump = (offset - self._last_offset) / 1e9
            raise InputError(f"{self.topic}: clock jump at message {n}: the header stamp moved {jump:+.3f} s "
                             f"against the bag clock (more than {self.max_jump_ns / 1e9:g} s; header "
                             f"{stamp} ns, bag {bag_ns} ns)")
        self._last_offset = offset
        self.stamps.append(stamp)


class BagSequence(Sequence):
    """A ROS bag (ROS 1, ROS 2 SQLite3 or MCAP) read as a sequence (see the module docstring).

    Attributes:
        topics: the topics chosen (:class:`TopicChoice`).
        kind: ``"ROS 1 bag"``, ``"ROS 2 bag (sqlite3)"``, ``"ROS 2 bag (mcap)"`` or ``"MCAP file"``.
        pose_times: (M,) seconds of the pose samples (empty without a pose topic).
    """

    format_name = "rosbag"
    pose_kind = "mocap"

    def __init__(self, path, settings: BagSettings = BagSettings()):
        path = Path(path)
        self.settings = settings
        self._lock = threading.Lock()
        self._reader, self.kind = open_reader(path)
        try:
            self._open(path, settings)
        except BaseException:
            self.close()
            raise

    def _open(self, path: Path, settings: BagSettings) -> None:
        reader = self._reader
        catalogue = BagTopics.of(reader)
        self.topics = choose_topics(catalogue, settings, path)
        topics = self.topics
        self._image_conns = catalogue.connections(reader, topics.image)
        wanted = {topics.image: "image"}
        for name, role in ((topics.imu, "imu"), (topics.camera_info, "info"), (topics.pose, "pose")):
            if name:
                wanted[name] = role
        conns = [c for c in reader.connections if c.topic in wanted]
        jump = int(round(settings.max_clock_jump_s * 1e9))
        images, imu_stamps, pose_stamps = _Stamps(topics.image, jump), _Stamps(topics.imu or "", jump), \
            _Stamps(topics.pose or "", jump)
        bag_ns, rank = array("q"), array("l")
        imu_values, pose_values, velocities = array("d"), array("d"), array("d")
        info_msg = None
        first_image = None
        try:
            for conn, t_bag, raw in reader.messages(connections=conns):
                role = wanted[conn.topic]
                if role == "image":
                    msg = reader.deserialize(raw, conn.msgtype)
                    stamp = stamp_ns(msg.header)
                    if first_image is None:
                        check_image_encoding(msg, conn.msgtype, f"{path}: {conn.topic}")
                        first_image = (msg, conn.msgtype)
                    rank.append(rank[-1] + 1 if bag_ns and bag_ns[-1] == t_bag else 0)
                    images.add(stamp, t_bag)
                    bag_ns.append(t_bag)
                elif role == "imu":
                    msg = reader.deserialize(raw, conn.msgtype)
                    imu_stamps.add(stamp_ns(msg.header), t_bag)
                    imu_values.extend(imu_sample(msg))
                elif role == "pose":
                    msg = reader.deserialize(raw, conn.msgtype)
                    pose_stamps.add(stamp_ns(msg.header), t_bag)
                    p, q, v = pose_sample(msg, conn.msgtype)
                    pose_values.extend(p + q)
                    if v is not None:
                        velocities.extend(v)
                elif info_msg is None:
                    info_msg = reader.deserialize(raw, conn.msgtype)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
        except Exception as exc:  # rosbags, the codecs and sqlite raise their own types
            raise reader_error(path, exc) from None
        if not len(images.stamps):
            raise InputError(f"{path}: no message on the image topic {topics.image} (an empty or truncated bag?)")
        self._stamps_ns = np.frombuffer(images.stamps, dtype=np.int64).copy()
        self._bag_ns = np.frombuffer(bag_ns, dtype=np.int64).copy()
        self._rank = np.asarray(rank, dtype=np.int32)
        self._t = self._stamps_ns / 1e9

        camera = self._camera(path, info_msg, first_image)
        imu, self.imu_missing_reason = self._imu(path, imu_stamps, imu_values)
        super().__init__(path, path.stem if path.is_file() else path.name, camera, imu)
        self._T_w_c, self._velocity = self._poses(path, pose_stamps, pose_values, velocities)
        self.pose_times = np.frombuffer(pose_stamps.stamps, dtype=np.int64) / 1e9

    # ------------------------------------------------------------------ open: calibration, IMU, poses
    def _camera(self, path: Path, info_msg, first_image) -> Camera:
        topics, calib = self.topics, self.settings.calibration
        msg, msgtype = first_image
        where = f"{path}: {topics.image}"
        image = image_from_message(msg, msgtype, where)
        h, w = image.shape[:2]
        if calib.camera is not None:
            camera = calib.camera.camera
            source = f"--calib {calib.camera.name}"
            if calib.camera.rostopic and calib.camera.rostopic != topics.image:
                log.warning("%s: --calib %s was calibrated on %s, the run reads %s", path, calib.camera.name,
                            calib.camera.rostopic, topics.image)
        elif info_msg is not None:
            rectified = self.settings.rectified
            rectified = "rect" in topics.image if rectified is None else rectified
            camera = camera_from_info(info_msg, f"{path}: {topics.camera_info}", rectified=rectified)
            source = f"CameraInfo {topics.camera_info}"
        else:
            raise InputError(f"{path}: no camera calibration: the bag has no CameraInfo topic for {topics.image}; "
                             "give --camera-info-topic or --calib camchain.yaml (Kalibr)")
        if (camera.width, camera.height) != (w, h):
            raise InputError(f"{where}: images are {w}x{h} but {source} says {camera.width}x{camera.height}")
        return camera

    def _imu(self, path: Path, stamps: _Stamps, values: array) -> tuple[ImuData | None, str]:
        topic, calib = self.topics.imu, self.settings.calibration
        if not topic:
            return None, f"{path} has no sensor_msgs/Imu topic chosen (--imu-topic)"
        if not len(stamps.stamps):
            return None, f"{path}: no message on the IMU topic {topic}"
        if calib.camera is None or calib.camera.T_c_i is None:
            return None, (f"{path}: the camera-IMU extrinsic is unknown: give --calib camchain.yaml with T_cam_imu "
                          "(Kalibr)")
        if calib.imu is None:
            return None, f"{path}: the IMU noise model is unknown: give --imu-calib imu.yaml (Kalibr)"
        v = np.frombuffer(values, dtype=np.float64).reshape(-1, 6)
        problem = imu_sample_problem(v[:, :3], v[:, 3:])
        if problem is not None:
            raise InputError(f"{path}: {topic} message {problem[0]}: {problem[1]}")
        t = np.frombuffer(stamps.stamps, dtype=np.int64) / 1e9
        imu = ImuData(t, v[:, :3].copy(), v[:, 3:].copy(), calib.camera.T_c_i, gravity_w=BAG_GRAVITY_W)
        return calibrated_imu(imu, calib), ""

    def _poses(self, path: Path, stamps: _Stamps, values: array, velocities: array):
        topic, s = self.topics.pose, self.settings
        if not topic or not len(stamps.stamps):
            return None, None
        T_i_c = np.eye(4)
        if s.pose_frame == "imu":
            cam = s.calibration.camera
            if cam is None or cam.T_c_i is None:
                raise InputError(f"{path}: the poses of {topic} are of the IMU frame (--pose-frame imu) and need the "
                                 "camera-IMU extrinsic: give --calib camchain.yaml with T_cam_imu, or --pose-frame "
                                 "camera, or --pose-topic none")
            T_i_c = invert_transform(cam.T_c_i)
        v = np.frombuffer(values, dtype=np.float64).reshape(-1, 7)
        q_wxyz = v[:, 3:7]
        norms = np.linalg.norm(q_wxyz, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
        if len(bad):
            raise InputError(f"{path}: {topic} message {int(bad[0])}: quaternion norm {norms[bad[0]]:.4f} is not 1")
        T_w_b = np.tile(np.eye(4), (len(v), 1, 1))
        T_w_b[:, :3, :3] = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]] / norms[:, None]).as_matrix()
        T_w_b[:, :3, 3] = v[:, :3]
        t = np.frombuffer(stamps.stamps, dtype=np.int64) / 1e9
        T, ok = interpolate_poses(self._t, t, T_w_b, 0.5 * s.max_pose_gap_s, bracketed_only=True)
        T_w_c = [T_k @ T_i_c if k else None for T_k, k in zip(T, ok)]
        velocity = None
        if len(velocities) and s.pose_frame == "imu":  # Odometry: twist in the body frame -> world
            v_b = np.frombuffer(velocities, dtype=np.float64).reshape(-1, 3)
            v_w = np.einsum("nij,nj->ni", T_w_b[:, :3, :3], v_b)
            vel = np.stack([np.interp(self._t, t, v_w[:, k]) for k in range(3)], 1)
            velocity = [row if k else None for row, k in zip(vel, ok)]
        if not ok.any():
            log.warning("%s: no frame lies between two samples of %s at most %g s apart: no frame has a pose "
                        "(--max-pose-gap)", path, topic, s.max_pose_gap_s)
        return T_w_c, velocity

    # ------------------------------------------------------------------ the sequence
    def __len__(self) -> int:
        return len(self._t)

    @property
    def has_gt_depth(self) -> bool:
        return False

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) image header stamps, seconds."""
        return self._t.copy()

    @property
    def stamps_ns(self) -> np.ndarray:
        """(N,) image header stamps, integer nanoseconds."""
        return self._stamps_ns.copy()

    @property
    def n_posed(self) -> int:
        return 0 if self._T_w_c is None else sum(T is not None for T in self._T_w_c)

    def read_image(self, index: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB of frame ``index``, read from the bag."""
        t_bag, rank = int(self._bag_ns[index]), int(self._rank[index])
        where = f"{self.root}: {self.topics.image} message at {t_bag} ns"
        with self._lock:
            if self._reader is None:
                raise InputError(f"{self.root}: the bag was closed")
            try:
                found = [(c, raw) for c, _, raw in
                         self._reader.messages(connections=self._image_conns, start=t_bag, stop=t_bag + 1)]
            except Exception as exc:
                raise reader_error(self.root, exc) from None
        if len(found) <= rank:
            raise InputError(f"{where}: not found on reading it again (the bag changed?)")
        conn, raw = found[rank]
        try:
            msg = self._reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise reader_error(self.root, exc) from None
        if stamp_ns(msg.header) != self._stamps_ns[index]:
            raise InputError(f"{where}: header stamp changed on reading it again (the bag changed?)")
        image = image_from_message(msg, conn.msgtype, where)
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(f"{where}: image is {image.shape[1]}x{image.shape[0]} but the camera is "
                             f"{self.camera.width}x{self.camera.height}")
        return image

    def frame(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(index)
        T = None if self._T_w_c is None else self._T_w_c[index]
        vel = None if self._velocity is None else self._velocity[index]
        return Frame(index=index, timestamp=float(self._t[index]), stem=str(int(self._stamps_ns[index])),
                     camera=self.camera, T_w_c=None if T is None else T.copy(),
                     load_image=lambda i=index: self.read_image(i), velocity_w=None if vel is None else vel.copy())

    def close(self) -> None:
        """Close the bag (frames can no longer load images)."""
        with self._lock:
            if self._reader is not None:
                try:
                    self._reader.close()
                except Exception:  # closing a reader that failed half-way
                    pass
                self._reader = None

    def __enter__(self) -> "BagSequence":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def detect_bag(path) -> bool:
    """A ``.bag``, ``.mcap`` or ``.db3`` file, or a ROS 2 bag folder (``metadata.yaml``)."""
    path = Path(path)
    if path.is_file():
        return path.suffix in (".bag", ".mcap", ".db3")
    return path.is_dir() and (path / "metadata.yaml").is_file()


def open_bag(path, settings: BagSettings = BagSettings()) -> BagSequence:
    """Open a bag as a :class:`BagSequence` (see the module docstring)."""
    return BagSequence(path, settings)


FORMAT = SequenceFormat(
    "rosbag", detect_bag, open_bag,
    "ROS 1 .bag, ROS 2 bag folder (sqlite3 / mcap) or .mcap file, through rosbags (docs/ros.md)",
)

__all__ = ["BAG_GRAVITY_W", "FORMAT", "BagSequence", "BagSettings", "POSE_FRAMES", "TopicChoice", "detect_bag", "open_bag"]
