"""ROS messages -> vio-depth arrays: images, camera info, IMU samples, poses (used by :mod:`vio_depth.io.bag`).

Conversions (ROS 1 and ROS 2 alike; ``rosbags`` gives both the ROS 2 field names):

==============================  ==========================================================================
message                         becomes
==============================  ==========================================================================
``sensor_msgs/Image``           (H, W, 3) uint8 RGB: ``mono8``/``8UC1`` repeated into 3 channels,
                                ``bgr8``/``8UC3``/``bgra8``/``rgba8``/``rgb8`` reordered, ``mono16``/``16UC1``
                                scaled to 8 bits (``round(v / 257)``, as the ASL loader), Bayer 8-bit
                                patterns demosaiced (OpenCV); rows honour ``step``, big-endian 16-bit honoured
``sensor_msgs/CompressedImage`` decoded by OpenCV (JPEG, PNG; 8 or 16 bits; codec warnings are errors,
                                damaged data a ``CorruptImageError``: the frame's status in a run);
                                ``compressedDepth`` is refused
``sensor_msgs/CameraInfo``      :class:`~vio_core.camera.Camera`: ``K``; ``plumb_bob`` (5) /
                                ``rational_polynomial`` (8) -> ``radtan``, ``equidistant`` (4) -> ``equidistant``;
                                for a rectified image topic ``P`` and no distortion
``sensor_msgs/Imu``             angular velocity (rad/s) and linear acceleration (m/s^2, specific force)
``geometry_msgs/PoseStamped``,  position + orientation quaternion of the pose's frame in the header frame
``PoseWithCovarianceStamped``,
``TransformStamped``,
``nav_msgs/Odometry``
==============================  ==========================================================================

Header stamps become integer nanoseconds (``sec * 10^9 + nanosec``).
"""

from __future__ import annotations

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.errors import CorruptImageError, InputError

from .decode import CorruptData, decode_image_checked

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
ODOMETRY = "nav_msgs/msg/Odometry"

IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
POSE_TYPES = (POSE_STAMPED, POSE_WITH_COVARIANCE, TRANSFORM_STAMPED, ODOMETRY)

#: raw image encodings read, with (channels, bytes per channel)
IMAGE_ENCODINGS = {
    "mono8": (1, 1), "8UC1": (1, 1), "mono16": (1, 2), "16UC1": (1, 2),
    "rgb8": (3, 1), "bgr8": (3, 1), "8UC3": (3, 1), "rgba8": (4, 1), "bgra8": (4, 1), "8UC4": (4, 1),
    "bayer_rggb8": (1, 1), "bayer_bggr8": (1, 1), "bayer_gbrg8": (1, 1), "bayer_grbg8": (1, 1),
}
_TO_RGB = {"bgr8": cv2.COLOR_BGR2RGB, "8UC3": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB,
           "bgra8": cv2.COLOR_BGRA2RGB, "8UC4": cv2.COLOR_BGRA2RGB,
           # OpenCV names Bayer patterns by the second row's first two pixels
           "bayer_rggb8": cv2.COLOR_BayerBG2RGB, "bayer_bggr8": cv2.COLOR_BayerRG2RGB,
           "bayer_gbrg8": cv2.COLOR_BayerGR2RGB, "bayer_grbg8": cv2.COLOR_BayerGB2RGB}
#: CameraInfo distortion models -> (vio_core.Camera model, accepted coefficient counts)
CAMERA_INFO_MODELS = {"plumb_bob": ("radtan", (4, 5)), "rational_polynomial": ("radtan", (8,)),
                      "equidistant": ("equidistant", (4,)), "fisheye": ("equidistant", (4,)), "": ("radtan", (0,)),
                      "none": ("radtan", (0,))}


def stamp_ns(header) -> int:
    """Integer nanoseconds of a ``std_msgs/Header``'s stamp."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _to_rgb(pixels: np.ndarray, encoding: str) -> np.ndarray:
    if pixels.dtype == np.uint16:
        pixels = np.round(pixels / 257.0).astype(np.uint8)
    if pixels.ndim == 2 and encoding in _TO_RGB:
        return np.ascontiguousarray(cv2.cvtColor(pixels, _TO_RGB[encoding]))
    if pixels.ndim == 2:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    if encoding in _TO_RGB:
        return np.ascontiguousarray(cv2.cvtColor(pixels, _TO_RGB[encoding]))
    return np.ascontiguousarray(pixels)


def check_image_encoding(msg, msgtype: str, where: str) -> None:
    """Refuse an image message vio-depth cannot read (before a run starts)."""
    if msgtype == IMAGE and msg.encoding not in IMAGE_ENCODINGS:
        raise InputError(f"{where}: unsupported image encoding {msg.encoding!r}; supported: "
                         f"{', '.join(IMAGE_ENCODINGS)}, or sensor_msgs/CompressedImage (jpeg, png)")
    if msgtype == COMPRESSED_IMAGE and "compresseddepth" in msg.format.lower().replace(" ", ""):
        raise InputError(f"{where}: compressedDepth images ({msg.format!r}) are depth maps, not camera images")


def raw_image(msg, where: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a ``sensor_msgs/Image`` (see the module table)."""
    check_image_encoding(msg, IMAGE, where)
    channels, size = IMAGE_ENCODINGS[msg.encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    row = w * channels * size
    if h <= 0 or w <= 0 or step < row or len(data) < step * (h - 1) + row:
        raise InputError(f"{where}: {msg.encoding} image of {w}x{h} with step {step} holds {len(data)} bytes "
                         f"(needs {step * (h - 1) + row})")
    if len(data) < step * h:
        data = np.concatenate([data, np.zeros(step * h - len(data), np.uint8)])
    rows = data[: step * h].reshape(h, step)[:, :row]
    if size == 2:
        pixels = rows.copy().view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)
    else:
        pixels = rows
    pixels = pixels.reshape(h, w, channels) if channels > 1 else pixels.reshape(h, w)
    return _to_rgb(pixels, msg.encoding)


def compressed_image(msg, where: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a ``sensor_msgs/CompressedImage`` (JPEG or PNG, 8 or 16 bits)."""
    check_image_encoding(msg, COMPRESSED_IMAGE, where)
    image, problem = decode_image_checked(bytes(np.asarray(msg.data, dtype=np.uint8)), cv2.IMREAD_UNCHANGED)
    if image is None and isinstance(problem, CorruptData):  # a status in a run: one damaged frame goes by
        raise CorruptImageError(where, f"damaged {msg.format or 'compressed'} image: {problem}")
    if image is None:
        raise InputError(f"{where}: cannot decode the {msg.format or 'compressed'} image"
                         f"{': ' + problem if problem else ''}")
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{where}: unsupported compressed image type {image.dtype} (8 or 16 bits expected)")
    if image.ndim == 3 and image.shape[2] == 4:
        return _to_rgb(image, "bgra8")
    return _to_rgb(image, "bgr8" if image.ndim == 3 else "mono8")


def image_from_message(msg, msgtype: str, where: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image message of either type."""
    return raw_image(msg, where) if msgtype == IMAGE else compressed_image(msg, where)


def camera_from_info(msg, where: str, *, rectified: bool = False) -> Camera:
    """The :class:`Camera` of a ``sensor_msgs/CameraInfo`` (``P`` and no distortion when ``rectified``)."""
    binning = (int(msg.binning_x), int(msg.binning_y))
    roi = msg.roi
    if binning not in ((0, 0), (1, 1), (0, 1), (1, 0)) or int(roi.width) or int(roi.height):
        raise InputError(f"{where}: CameraInfo with binning {binning} or a region of interest is not supported")
    w, h = int(msg.width), int(msg.height)
    # ROS 1 names the arrays D, K, R, P; ROS 2 d, k, r, p
    k_, d_, p_ = (msg.k, msg.d, msg.p) if hasattr(msg, "k") else (msg.K, msg.D, msg.P)
    if rectified:
        P = np.asarray(p_, dtype=np.float64).reshape(3, 4)
        K, dist, model = P[:, :3], (), "radtan"
    else:
        K = np.asarray(k_, dtype=np.float64).reshape(3, 3)
        name = str(msg.distortion_model)
        d = [float(v) for v in np.asarray(d_, dtype=np.float64)]
        if name not in CAMERA_INFO_MODELS:
            raise InputError(f"{where}: distortion model {name!r} is not supported; valid: "
                             f"{', '.join(repr(k) for k in CAMERA_INFO_MODELS)}")
        model, sizes = CAMERA_INFO_MODELS[name]
        if not any(d):
            d = []
        elif name == "plumb_bob" and len(d) == 5 and d[4] == 0.0:
            d = d[:4]
        if d and len(d) not in sizes:
            raise InputError(f"{where}: {name} takes {' or '.join(map(str, sizes))} coefficients, got {len(d)}")
        dist = tuple(d)
    if not np.all(np.isfinite(K)) or K[0, 1] != 0.0:
        raise InputError(f"{where}: camera matrix must be finite with zero skew, got {K.tolist()}")
    try:
        return Camera.from_K(K, w, h, dist, model)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def imu_sample(msg) -> tuple[float, float, float, float, float, float]:
    """``(gx, gy, gz, ax, ay, az)`` of a ``sensor_msgs/Imu``: rad/s and m/s^2."""
    w, a = msg.angular_velocity, msg.linear_acceleration
    return float(w.x), float(w.y), float(w.z), float(a.x), float(a.y), float(a.z)


def pose_sample(msg, msgtype: str) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...] | None]:
    """``(position (x, y, z), quaternion (w, x, y, z), body velocity (x, y, z) or None)`` of a pose message.

    The velocity is the ``Odometry`` twist's linear part, which ROS expresses in the child
    (body) frame; the other types carry none.
    """
    velocity = None
    if msgtype == TRANSFORM_STAMPED:
        p, q = msg.transform.translation, msg.transform.rotation
    elif msgtype == POSE_STAMPED:
        p, q = msg.pose.position, msg.pose.orientation
    elif msgtype == POSE_WITH_COVARIANCE:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
    elif msgtype == ODOMETRY:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        v = msg.twist.twist.linear
        velocity = (float(v.x), float(v.y), float(v.z))
    else:
        raise InputError(f"unsupported pose message type {msgtype}; supported: {', '.join(POSE_TYPES)}")
    return (float(p.x), float(p.y), float(p.z)), (float(q.w), float(q.x), float(q.y), float(q.z)), velocity


__all__ = [
    "CAMERA_INFO", "CAMERA_INFO_MODELS", "COMPRESSED_IMAGE", "IMAGE", "IMAGE_ENCODINGS", "IMAGE_TYPES", "IMU",
    "ODOMETRY", "POSE_STAMPED", "POSE_TYPES", "POSE_WITH_COVARIANCE", "TRANSFORM_STAMPED", "camera_from_info",
    "check_image_encoding", "compressed_image", "image_from_message", "imu_sample", "pose_sample", "raw_image",
    "stamp_ns",
]
