"""Writing ROS messages and bags: arrays -> ROS messages (:class:`RosMessages`), streamed into a
ROS 1 ``.bag``, a ROS 2 SQLite3 bag or a ROS 2 MCAP bag (:class:`BagWriter`, through ``rosbags``).

Used to convert a folder sequence into a bag (tests, benchmarks, users who want a bag of a
dataset) and by the run's ROS outputs (:mod:`vio_depth.export.rosout`). Messages are
built from the standard definitions of ROS 1 Noetic or ROS 2 Humble (``rosbags``' type
stores), so any ROS tool reads them. Stamps are integer nanoseconds. Usage::

    msgs = RosMessages(ros1=False)
    with BagWriter("out.bag2", "ros2") as w:
        w.write("/cam0/image_raw", msgs.image(t_ns, "cam0", grey, "mono8"))
        w.write("/imu0", msgs.imu(t_ns, "imu0", gyro, accel))
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import InputError

from .asl import AslSequence, asl_root, read_asl_images_csv, read_asl_table

#: bag kinds :class:`BagWriter` writes
BAG_KINDS = ("ros1", "ros2", "mcap")
#: 16-bit and float image encodings -> numpy dtype
_DTYPES = {"mono8": np.uint8, "8UC1": np.uint8, "rgb8": np.uint8, "bgr8": np.uint8, "mono16": np.uint16,
           "16UC1": np.uint16, "32FC1": np.float32}
#: PointField datatypes
_POINT_FIELD = {np.dtype(np.float32): 7, np.dtype(np.float64): 8, np.dtype(np.uint8): 2, np.dtype(np.uint16): 4,
                np.dtype(np.int32): 5, np.dtype(np.uint32): 6}


def _split_ns(stamp_ns: int) -> tuple[int, int]:
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise InputError(f"negative stamp {stamp_ns} ns")
    return stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000


class RosMessages:
    """Builds standard ROS messages from arrays (ROS 1 Noetic or ROS 2 Humble definitions).

    Attributes:
        typestore: the ``rosbags`` type store of the messages.
        ros1: ROS 1 messages (serialised for ROS 1 bags) or ROS 2 ones (CDR).
    """

    def __init__(self, ros1: bool = False):
        self.ros1 = ros1
        self.typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        self._t = self.typestore.types

    def serialize(self, msg) -> bytes:
        """The message's bytes (ROS 1 serialisation or CDR, little endian)."""
        if self.ros1:
            return bytes(self.typestore.serialize_ros1(msg, msg.__msgtype__))
        return bytes(self.typestore.serialize_cdr(msg, msg.__msgtype__))

    def deserialize(self, data: bytes, msgtype: str):
        if self.ros1:
            return self.typestore.deserialize_ros1(data, msgtype)
        return self.typestore.deserialize_cdr(data, msgtype)

    def _new(self, msgtype: str, **fields):
        cls = self._t[msgtype]
        names = {f.name for f in dataclasses.fields(cls)}
        if "seq" in names and "seq" not in fields:
            fields["seq"] = 0
        # ROS 1 spells the camera info arrays in capitals
        fields = {(k.upper() if k not in names and k.upper() in names else k): v for k, v in fields.items()}
        return cls(**fields)

    def header(self, stamp_ns: int, frame_id: str):
        sec, nsec = _split_ns(stamp_ns)
        stamp = self._new("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
        return self._new("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)

    def _vector(self, v):
        return self._new("geometry_msgs/msg/Vector3", x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def _quaternion(self, q_wxyz):
        return self._new("geometry_msgs/msg/Quaternion", x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]),
                         w=float(q_wxyz[0]))

    def _pose(self, p, q_wxyz):
        point = self._new("geometry_msgs/msg/Point", x=float(p[0]), y=float(p[1]), z=float(p[2]))
        return self._new("geometry_msgs/msg/Pose", position=point, orientation=self._quaternion(q_wxyz))

    def image(self, stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str):
        """``sensor_msgs/Image`` of ``pixels`` ((H, W) or (H, W, 3) of the encoding's dtype), rows packed."""
        if encoding not in _DTYPES:
            raise InputError(f"image encoding {encoding!r}: writable are {', '.join(_DTYPES)}")
        pixels = np.ascontiguousarray(pixels)
        if pixels.dtype != _DTYPES[encoding]:
            raise InputError(f"{encoding} image: expected {np.dtype(_DTYPES[encoding])} pixels, got {pixels.dtype}")
        h, w = pixels.shape[:2]
        data = pixels.astype(pixels.dtype.newbyteorder("<"), copy=False).view(np.uint8).reshape(-1)
        return self._new("sensor_msgs/msg/Image", header=self.header(stamp_ns, frame_id), height=h, width=w,
                         encoding=encoding, is_bigendian=0, step=len(data) // h, data=data)

    def compressed_image(self, stamp_ns: int, frame_id: str, data: bytes, fmt: str):
        """``sensor_msgs/CompressedImage`` of encoded ``data`` (``fmt``: ``jpeg`` or ``png``)."""
        return self._new("sensor_msgs/msg/CompressedImage", header=self.header(stamp_ns, frame_id), format=fmt,
                         data=np.frombuffer(data, dtype=np.uint8))

    def camera_info(self, stamp_ns: int, frame_id: str, camera: Camera):
        """``sensor_msgs/CameraInfo`` of ``camera`` (``plumb_bob`` / ``rational_polynomial`` / ``equidistant``)."""
        K = camera.K
        if camera.model == "equidistant":
            model, d = "equidistant", list(camera.dist) or [0.0] * 4
        elif len(camera.dist) == 8:
            model, d = "rational_polynomial", list(camera.dist)
        else:
            model, d = "plumb_bob", (list(camera.dist) + [0.0] * 5)[:5]
        P = np.hstack([K, np.zeros((3, 1))])
        roi = self._new("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self._new("sensor_msgs/msg/CameraInfo", header=self.header(stamp_ns, frame_id), height=camera.height,
                         width=camera.width, distortion_model=model, d=np.asarray(d, dtype=np.float64),
                         k=K.reshape(-1).astype(np.float64), r=np.eye(3).reshape(-1), p=P.reshape(-1),
                         binning_x=0, binning_y=0, roi=roi)

    def imu(self, stamp_ns: int, frame_id: str, gyro, accel):
        """``sensor_msgs/Imu``: ``gyro`` (3,) rad/s, ``accel`` (3,) m/s^2; no orientation (covariance[0] = -1)."""
        no_orientation = np.zeros(9)
        no_orientation[0] = -1.0
        return self._new("sensor_msgs/msg/Imu", header=self.header(stamp_ns, frame_id),
                         orientation=self._quaternion((1.0, 0.0, 0.0, 0.0)), orientation_covariance=no_orientation,
                         angular_velocity=self._vector(gyro), angular_velocity_covariance=np.zeros(9),
                         linear_acceleration=self._vector(accel), linear_acceleration_covariance=np.zeros(9))

    def pose_stamped(self, stamp_ns: int, frame_id: str, p, q_wxyz):
        """``geometry_msgs/PoseStamped``: position ``p`` (3,) metres, quaternion ``q_wxyz`` (4,)."""
        return self._new("geometry_msgs/msg/PoseStamped", header=self.header(stamp_ns, frame_id),
                         pose=self._pose(p, q_wxyz))

    def transform_stamped(self, stamp_ns: int, parent: str, child: str, p, q_wxyz):
        """``geometry_msgs/TransformStamped``: the pose of ``child`` in ``parent``."""
        tf = self._new("geometry_msgs/msg/Transform", translation=self._vector(p), rotation=self._quaternion(q_wxyz))
        return self._new("geometry_msgs/msg/TransformStamped", header=self.header(stamp_ns, parent),
                         child_frame_id=child, transform=tf)

    def odometry(self, stamp_ns: int, parent: str, child: str, p, q_wxyz, velocity_body=(0.0, 0.0, 0.0)):
        """``nav_msgs/Odometry``: pose of ``child`` in ``parent``, linear velocity in ``child`` (m/s)."""
        pose = self._new("geometry_msgs/msg/PoseWithCovariance", pose=self._pose(p, q_wxyz), covariance=np.zeros(36))
        twist = self._new("geometry_msgs/msg/Twist", linear=self._vector(velocity_body),
                          angular=self._vector((0.0, 0.0, 0.0)))
        twist_cov = self._new("geometry_msgs/msg/TwistWithCovariance", twist=twist, covariance=np.zeros(36))
        return self._new("nav_msgs/msg/Odometry", header=self.header(stamp_ns, parent), child_frame_id=child,
                         pose=pose, twist=twist_cov)

    def tf(self, transforms: list):
        """``tf2_msgs/TFMessage`` of ``TransformStamped`` messages."""
        return self._new("tf2_msgs/msg/TFMessage", transforms=list(transforms))

    def point_cloud(self, stamp_ns: int, frame_id: str, fields: dict):
        """``sensor_msgs/PointCloud2``, unorganised (height 1), of equal-length 1-D arrays
        ``fields`` (name -> (N,) float32/float64/uint8/...), packed in the given order."""
        arrays = {k: np.asarray(v) for k, v in fields.items()}
        n = len(next(iter(arrays.values()))) if arrays else 0
        dtype = np.dtype([(k, a.dtype.newbyteorder("<")) for k, a in arrays.items()])
        packed = np.zeros(n, dtype=dtype)
        pf = []
        for k, a in arrays.items():
            check_array(k, a, (n,))
            if a.dtype not in _POINT_FIELD:
                raise InputError(f"point field {k}: unsupported dtype {a.dtype}")
            packed[k] = a
            pf.append(self._new("sensor_msgs/msg/PointField", name=k, offset=dtype.fields[k][1],
                                datatype=_POINT_FIELD[a.dtype], count=1))
        data = packed.view(np.uint8).reshape(-1) if n else np.zeros(0, np.uint8)
        return self._new("sensor_msgs/msg/PointCloud2", header=self.header(stamp_ns, frame_id), height=1, width=n,
                         fields=pf, is_bigendian=False, point_step=dtype.itemsize, row_step=dtype.itemsize * n,
                         data=data, is_dense=False)


class BagWriter:
    """Streams messages into a new bag: ``ros1`` (``.bag`` file), ``ros2`` (SQLite3 folder) or
    ``mcap`` (ROS 2 folder with MCAP storage). Connections are added on a topic's first message.

    Args:
        path: the bag file (``ros1``) or folder (``ros2``, ``mcap``); must not exist.
        kind: one of :data:`BAG_KINDS`.
    """

    def __init__(self, path, kind: str):
        if kind not in BAG_KINDS:
            raise InputError(f"bag kind {kind!r}: expected one of {', '.join(BAG_KINDS)}")
        self.path = Path(path)
        if self.path.exists():
            raise InputError(f"{self.path}: already exists (a bag is written new)")
        if kind == "ros1" and self.path.suffix != ".bag":
            raise InputError(f"{self.path}: a ROS 1 bag is named *.bag")
        self.kind = kind
        self.messages = RosMessages(ros1=kind == "ros1")
        if kind == "ros1":
            self._writer = Ros1Writer(self.path)
        else:
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self._writer = Ros2Writer(self.path, version=9, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[str, object] = {}

    def write_raw(self, topic: str, msgtype: str, bag_ns: int, data: bytes) -> None:
        """Write an already serialised message of ``msgtype`` (serialised for this bag's ROS version)."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.messages.typestore)
            self._connections[topic] = conn
        self._writer.write(conn, int(bag_ns), data)

    def write(self, topic: str, msg, bag_ns: int | None = None) -> None:
        """Write ``msg`` (built by :attr:`messages`) on ``topic`` at bag time ``bag_ns`` (default: its header stamp)."""
        if bag_ns is None:
            header = msg.header if hasattr(msg, "header") else msg.transforms[0].header
            bag_ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        self.write_raw(topic, msg.__msgtype__, bag_ns, self.messages.serialize(msg))

    def close(self) -> Path:
        self._writer.close()
        return self.path

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: image forms :func:`asl_to_bag` writes
IMAGE_FORMS = ("raw", "png", "jpeg")
#: pose message types :func:`asl_to_bag` writes
POSE_FORMS = ("pose", "transform", "odometry")


def asl_to_bag(asl_folder, path, kind: str, *, image_form: str = "raw", pose_form: str = "pose",
               image_topic: str = "/cam0/image_raw", imu_topic: str = "/imu0", info_topic: str = "/cam0/camera_info",
               pose_topic: str = "/groundtruth") -> Path:
    """Convert an ASL folder (EuRoC / TUM-VI layout) into a bag, streaming.

    The numbers are the folder's own (nanosecond stamps, the csv values), so a run on the
    bag with the folder's calibration as Kalibr files equals a run on the folder
    (docs/ros.md). Images: ``raw`` (``mono8`` / ``bgr8`` as the PNG holds, ``mono16`` for
    16-bit), ``png`` (the PNG files' own bytes, ``CompressedImage``) or ``jpeg`` (re-encoded,
    lossy). Ground truth (the IMU frame's pose) as ``PoseStamped``, ``TransformStamped`` or
    ``Odometry`` (its twist: the 17-column table's velocity in the body frame; an 8-column
    table has none and is refused). Bag time = header stamp.
    """
    if image_form not in IMAGE_FORMS or pose_form not in POSE_FORMS:
        raise InputError(f"image_form must be one of {IMAGE_FORMS}, pose_form one of {POSE_FORMS}")
    seq = AslSequence(asl_folder)
    mav0 = asl_root(asl_folder)
    t_images, names, _ = read_asl_images_csv(mav0 / "cam0" / "data.csv")
    with BagWriter(path, kind) as w:
        m = w.messages
        if (mav0 / "imu0").is_dir():
            t_imu, v, _ = read_asl_table(mav0 / "imu0" / "data.csv", 7, "IMU", "t, w, a")
            for t, row in zip(t_imu, v):
                w.write(imu_topic, m.imu(int(t), "imu0", row[:3], row[3:6]))
        if seq.ground_truth is not None:
            t_gt, v, _ = read_asl_table(seq.ground_truth.path, (8, 17), "ground truth", "t, p, q[, v, bw, ba]")
            if pose_form == "odometry" and v.shape[1] < 16:
                raise InputError(f"{seq.ground_truth.path}: Odometry needs velocities (the 17-column table)")
            for t, row in zip(t_gt, v):
                if pose_form == "pose":
                    msg = m.pose_stamped(int(t), "world", row[:3], row[3:7])
                elif pose_form == "transform":
                    msg = m.transform_stamped(int(t), "world", "imu0", row[:3], row[3:7])
                else:  # the twist is in the body frame: v_b = R_w_b^T v_w
                    q = row[3:7] / np.linalg.norm(row[3:7])
                    R_w_b = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
                    msg = m.odometry(int(t), "world", "imu0", row[:3], row[3:7], R_w_b.T @ row[7:10])
                w.write(pose_topic, msg)
        for t, name in zip(t_images, names):
            t = int(t)
            data = (mav0 / "cam0" / "data" / name).read_bytes()
            if image_form == "png":
                msg = m.compressed_image(t, "cam0", data, "png")
            else:
                pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
                if image_form == "jpeg":
                    ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])
                    msg = m.compressed_image(t, "cam0", buf.tobytes(), "jpeg")
                elif pixels.ndim == 2:
                    msg = m.image(t, "cam0", pixels, "mono16" if pixels.dtype == np.uint16 else "mono8")
                else:
                    msg = m.image(t, "cam0", np.ascontiguousarray(pixels[:, :, :3]), "bgr8")
            w.write(image_topic, msg)
            w.write(info_topic, m.camera_info(t, "cam0", seq.camera))
    return Path(path)


__all__ = ["BAG_KINDS", "BagWriter", "IMAGE_FORMS", "POSE_FORMS", "RosMessages", "asl_to_bag"]
