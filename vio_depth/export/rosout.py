"""A run's results as ROS messages: an MCAP file (``--save-mcap``) or a ROS 2 SQLite3 bag (``--save-rosbag2``).

For every frame with metric depth, stamped with the frame's time (its header stamp for
bags and ASL folders, whose stems are nanosecond stamps):

==========================  =====================================  ===============================================
topic (default names)       type                                   content
==========================  =====================================  ===============================================
``/vio_depth/depth``        ``sensor_msgs/Image`` ``32FC1``        metric depth, metres, NaN = invalid (bit-exact)
``/vio_depth/depth_kitti``  ``sensor_msgs/Image`` ``16UC1``        metres x 256, 0 = invalid (as ``depth/*.png``)
``/vio_depth/depth_sigma``  ``sensor_msgs/Image`` ``32FC1``        1-sigma of the depth from the fit, metres
``/vio_depth/camera_info``  ``sensor_msgs/CameraInfo``             the camera (distortion of the raw image)
``/vio_depth/points``       ``sensor_msgs/PointCloud2``            the frame's metric points in the camera frame:
                                                                   ``x y z`` (float32 m), ``sigma`` (float32 m, NaN
                                                                   unknown), ``inlier`` (uint8) of the fit
==========================  =====================================  ===============================================

and at the end of the run, for every frame of the run's trajectory (``trajectory.tum``):
``/vio_depth/pose`` (``geometry_msgs/PoseStamped`` of the camera in ``world``) and ``/tf``
(``tf2_msgs/TFMessage``, ``world`` -> ``camera``), so that RViz and Foxglove place the
depth images and the points. Frame ids: ``world`` and ``camera`` (the camera's optical
frame: x right, y down, z forward), both nameable, as are the topics
(:class:`RosOutputSettings`).

The MCAP file uses the ``ros2`` profile (``ros2msg`` schemas, CDR messages, chunked and
indexed, zstd), the layout ``ros2 bag record`` writes, so Foxglove, ``ros2 bag play`` and
``rosbags`` open it as it is. Messages come in the order frames finish; a frame the
offline backfill gives depth is written when it does (earlier in time than its
neighbours: readers order by the index).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer as McapWriter
from scipy.spatial.transform import Rotation

from vio_core.errors import InputError, SettingsError

from ..evaluation import CameraTrajectory
from ..io.bag_writer import BagWriter, RosMessages
from ..io.depth_png import encode_depth_uint16
from ..rescale import depth_sigma_map

#: output kinds
ROS_OUTPUT_KINDS = ("mcap", "rosbag2")


@dataclass(frozen=True)
class RosOutputSettings:
    """Topic names and frame ids of the ROS outputs (each topic name may be set on its own).

    Attributes:
        prefix: namespace of the topics left empty below (``/vio_depth``).
        world_frame / camera_frame: frame ids of the world and of the camera's optical frame.
    """

    prefix: str = "/vio_depth"
    world_frame: str = "world"
    camera_frame: str = "camera"
    depth_topic: str = ""
    depth_kitti_topic: str = ""
    sigma_topic: str = ""
    camera_info_topic: str = ""
    points_topic: str = ""
    pose_topic: str = ""
    tf_topic: str = "/tf"

    def __post_init__(self):
        if not self.prefix.startswith("/") or self.prefix.endswith("/") and self.prefix != "/":
            raise SettingsError(f"topic prefix {self.prefix!r} must start with '/' and not end with one")
        for name in ("world_frame", "camera_frame"):
            if not getattr(self, name) or "/" in getattr(self, name):
                raise SettingsError(f"{name} {getattr(self, name)!r}: a frame id is a non-empty name without '/'")

    def topic(self, kind: str) -> str:
        """The topic of ``kind`` (``depth``, ``depth_kitti``, ``sigma``, ``camera_info``, ``points``, ``pose``)."""
        given = getattr(self, f"{kind}_topic")
        default = {"sigma": "depth_sigma"}.get(kind, kind)
        return given or f"{self.prefix.rstrip('/')}/{default}"


def frame_stamp_ns(frame) -> int:
    """The frame's stamp in nanoseconds: its stem when that is the integer stamp (bags, ASL),
    else ``round(timestamp * 1e9)``."""
    approx = int(round(frame.timestamp * 1e9))
    stem = frame.stem
    if stem.isdigit() and abs(int(stem) - approx) <= 1000:
        return int(stem)
    return approx


def _q_wxyz(R: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


class McapFileOutput:
    """Messages into one MCAP file (``ros2`` profile); schemas and channels on first use."""

    def __init__(self, path, messages: RosMessages):
        self.path = Path(path)
        self.messages = messages
        self._file = open(self.path, "wb")
        self._writer = McapWriter(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="vio-depth")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0

    def write(self, topic: str, msg, log_ns: int) -> None:
        msgtype = msg.__msgtype__
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(msgtype)
            if schema is None:
                text, _ = self.messages.typestore.generate_msgdef(msgtype, ros_version=2)
                schema = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=text.encode())
                self._schemas[msgtype] = schema
            channel = self._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
            self._channels[topic] = channel
        self._writer.add_message(channel_id=channel, log_time=int(log_ns), publish_time=int(log_ns),
                                 data=self.messages.serialize(msg), sequence=self._sequence)
        self._sequence += 1

    def close(self) -> None:
        self._writer.finish()
        self._file.close()

    def abort(self) -> None:
        """Close the file as it is (no summary: the run failed; the staging folder holds it)."""
        self._file.close()


class Rosbag2Output:
    """Messages into a ROS 2 SQLite3 bag folder (through ``rosbags``).

    SQLite connections belong to the thread that opened them, while a run writes from its
    writer thread and closes from the calling one: the messages go to an MCAP file beside
    the folder first, which :meth:`close` copies into the bag, in time order, and removes.
    """

    def __init__(self, path, messages: RosMessages):
        self.path = Path(path)
        if self.path.exists():
            raise InputError(f"{self.path}: already exists (a bag is written new)")
        self.messages = messages
        self._spool_path = self.path.with_name(self.path.name + ".spool.mcap")
        self._spool = McapFileOutput(self._spool_path, messages)

    def write(self, topic: str, msg, log_ns: int) -> None:
        self._spool.write(topic, msg, log_ns)

    def close(self) -> None:
        self._spool.close()
        with open(self._spool_path, "rb") as fh, BagWriter(self.path, "ros2") as bag:
            bag.messages = self.messages
            reader = make_reader(fh)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                bag.write_raw(channel.topic, schema.name, message.log_time, message.data)
        self._spool_path.unlink()

    def abort(self) -> None:
        self._spool.abort()
        self._spool_path.unlink(missing_ok=True)


class RosRunWriter:
    """The run's results as ROS messages into ``path`` (``kind``: ``mcap`` file or ``rosbag2`` folder).

    A frame sink of :func:`vio_depth.run.run_sequence`: :meth:`add_frame` per finished frame
    (in the writer thread), :meth:`finish` with the run's trajectory, :meth:`abort` on failure.
    Each frame is written once (a frame the backfill gives depth had none before).
    """

    def __init__(self, path, kind: str = "mcap", settings: RosOutputSettings = RosOutputSettings()):
        if kind not in ROS_OUTPUT_KINDS:
            raise InputError(f"ROS output kind {kind!r}: expected one of {', '.join(ROS_OUTPUT_KINDS)}")
        self.path = Path(path)
        self.kind = kind
        self.settings = settings
        self.messages = RosMessages(ros1=False)
        self._out = (McapFileOutput if kind == "mcap" else Rosbag2Output)(self.path, self.messages)
        self._written: set[int] = set()
        self.counts: dict[str, int] = {}

    def _write(self, kind: str, msg, stamp: int) -> None:
        topic = self.settings.tf_topic if kind == "tf" else self.settings.topic(kind)
        self._out.write(topic, msg, stamp)
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def add_frame(self, frame, result) -> None:
        """Write the depth, sigma, camera info and points of ``result`` (a ``FrameResult``) of
        ``frame`` (a ``Frame``); nothing for a frame without depth or already written."""
        if result.depth is None or frame.index in self._written:
            return
        self._written.add(frame.index)
        m, s, t = self.messages, self.settings, frame_stamp_ns(frame)
        cam = s.camera_frame
        depth = np.asarray(result.depth, dtype=np.float32)
        self._write("depth", m.image(t, cam, depth, "32FC1"), t)
        self._write("depth_kitti", m.image(t, cam, encode_depth_uint16(depth), "16UC1"), t)
        if result.disparity is not None and result.fit is not None:
            sigma = depth_sigma_map(result.disparity, result.fit).astype(np.float32)
            self._write("sigma", m.image(t, cam, sigma, "32FC1"), t)
        self._write("camera_info", m.camera_info(t, cam, frame.camera), t)
        uv = result.points_uv
        if uv is not None and len(uv):
            z = np.asarray(result.points_depth, dtype=np.float64)
            p = frame.camera.backproject(frame.camera.undistort_points(uv), z).astype(np.float32)
            n = len(z)
            sigma = np.full(n, np.nan, np.float32) if result.points_sigma is None else \
                np.asarray(result.points_sigma, dtype=np.float32)
            inlier = np.ones(n, np.uint8) if result.points_inlier is None else \
                np.asarray(result.points_inlier, dtype=np.uint8)
            self._write("points", m.point_cloud(t, cam, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "sigma": sigma,
                                                          "inlier": inlier}), t)

    def finish(self, sequence, trajectory: CameraTrajectory | None) -> Path:
        """Write the camera poses (``pose`` and ``tf``) and close the file.

        Args:
            sequence: the run's sequence (its frames' stamps: trajectory times are seconds).
            trajectory: the run's camera trajectory (``t`` seconds, ``T_w_c``), or None.
        """
        if trajectory is not None and len(trajectory):
            m, s = self.messages, self.settings
            frames = (sequence.frame(i) for i in range(len(sequence)))
            exact = {float(f.timestamp): frame_stamp_ns(f) for f in frames}
            for t, T in zip(trajectory.t, trajectory.T_w_c):
                ns = exact.get(float(t), int(round(float(t) * 1e9)))
                q, p = _q_wxyz(T[:3, :3]), T[:3, 3]
                self._write("pose", m.pose_stamped(ns, s.world_frame, p, q), ns)
                self._write("tf", m.tf([m.transform_stamped(ns, s.world_frame, s.camera_frame, p, q)]), ns)
        self._out.close()
        return self.path

    def abort(self) -> None:
        """Close the file after a failed run (the staging folder holding it is kept or discarded by the run)."""
        self._out.abort()


__all__ = ["ROS_OUTPUT_KINDS", "RosOutputSettings", "RosRunWriter", "frame_stamp_ns"]
