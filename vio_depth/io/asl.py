"""EuRoC / TUM-VI folders in the ASL layout (``mav0/``), auto-detected as format ``asl``.

Layout read (``ROOT`` is the folder holding ``mav0/``, or ``mav0/`` itself)::

    mav0/cam0/data.csv        "#timestamp [ns],filename" then "t_ns,<file>" per image
    mav0/cam0/data/<file>     8- or 16-bit grey (or colour) PNG images
    mav0/cam0/sensor.yaml     T_BS (camera-to-body), resolution, intrinsics [fu, fv, cu, cv],
                              camera_model: pinhole, distortion_model: radial-tangential
                              (radtan) or equidistant, distortion_coefficients
    mav0/imu0/data.csv        "t_ns, w_x, w_y, w_z [rad/s], a_x, a_y, a_z [m/s^2]" (optional
                              folder: without it the sequence has no IMU)
    mav0/imu0/sensor.yaml     T_BS (IMU-to-body), gyroscope_noise_density,
                              gyroscope_random_walk, accelerometer_noise_density,
                              accelerometer_random_walk (continuous-time, Kalibr units)
    mav0/state_groundtruth_estimate0/data.csv   optional ground truth, 8 columns
                              "t_ns, p_x, p_y, p_z [m], q_w, q_x, q_y, q_z" or 17 with
                              "v_x, v_y, v_z [m/s], bw_x.. [rad/s], ba_x.. [m/s^2]" appended;
                              the pose of the frame S of its own sensor.yaml's T_BS (identity
                              when absent) in the world R. ``mocap0/`` is read the same way
                              when ``state_groundtruth_estimate0/`` is absent (TUM-VI).

Conventions: timestamps are integer nanoseconds on one clock; they become seconds
(``t_ns / 1e9``) in :class:`~vio_depth.frame.Frame` and :class:`~vio_depth.frame.ImuData`.
``T_BS`` maps sensor-frame points into the body frame. Camera poses are
``T_w_c = T_R_S T_BS_gt^-1 T_BS_cam``; the IMU-to-camera transform is
``T_c_i = T_BS_cam^-1 T_BS_imu``; gravity is ``(0, 0, -9.81)`` in the world (z up, as in
EuRoC's Vicon frame). A frame takes a pose only when two ground-truth samples at most
``AslSettings.max_pose_gap_s`` apart bracket its timestamp (translation interpolated
linearly, rotation along the geodesic: :func:`~vio_depth.io.tables.interpolate_poses`
with ``bracketed_only``); other frames have ``T_w_c`` None (EuRoC's ground
truth starts about 1 s after its images; TUM-VI's covers only the start and the end). A
sequence without ground truth loads with no poses at all. Ground-truth velocities become
``Frame.velocity_w`` only when the ground-truth sensor and the IMU share their origin (both
are the body frame in EuRoC); the full table, with biases when given, is
:attr:`AslSequence.ground_truth`.

Every malformed input raises :class:`~vio_core.errors.SequenceFormatError` naming the file
and, where there is one, the line (the csv files are read by
:func:`~vio_depth.io.tables.read_text_table`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, SequenceFormatError, SettingsError
from vio_core.geometry import invert_transform
from vio_core.limits import MAX_TEXT_BYTES, read_limited, too_large

from ..frame import Frame, ImuData, imu_sample_problem
from .base import Sequence, SequenceFormat
from .decode import decode_image
from .images import read_image_bytes
from .tables import (
    QUATERNION_NORM_TOLERANCE,
    TextTable,
    interpolate_poses,
    read_text_table,
    stays_inside,
    yaml_float,
)

#: ASL distortion model names -> vio_core.Camera models
DISTORTION_MODEL_NAMES = {"radial-tangential": "radtan", "radtan": "radtan", "equidistant": "equidistant",
                          "equi": "equidistant", "fisheye": "equidistant", "none": "radtan"}
#: world gravity of ASL datasets (Vicon / Leica world, z up)
ASL_GRAVITY_W = (0.0, 0.0, -9.81)
#: ground-truth sensor and IMU origins closer than this (metres) count as one point (velocity usable)
SAME_ORIGIN_TOLERANCE_M = 1e-3
_GT_FOLDERS = ("state_groundtruth_estimate0", "mocap0")
_IMU_NOISE_KEYS = {"gyro_noise": "gyroscope_noise_density", "gyro_bias_walk": "gyroscope_random_walk",
                   "accel_noise": "accelerometer_noise_density", "accel_bias_walk": "accelerometer_random_walk"}


@dataclass(frozen=True)
class AslSettings:
    """Options of the ASL loader.

    Attributes:
        max_pose_gap_s: seconds; a frame takes a ground-truth pose only when two samples at
            most this far apart bracket its timestamp (EuRoC: 200 Hz, 5 ms spacing).
    """

    max_pose_gap_s: float = 0.02

    def __post_init__(self):
        if not self.max_pose_gap_s > 0:
            raise SettingsError(f"AslSettings.max_pose_gap_s must be positive, got {self.max_pose_gap_s}")


@dataclass(frozen=True)
class AslGroundTruth:
    """Ground-truth table of an ASL sequence, mapped to the IMU frame.

    Attributes:
        t: (N,) seconds.
        T_w_i: (N, 4, 4) IMU-to-world poses, metres.
        velocity_w: (N, 3) m/s world velocity of the IMU origin, or None (not in the file,
            or the ground-truth sensor origin is not the IMU's).
        gyro_bias: (N, 3) rad/s, or None. accel_bias: (N, 3) m/s^2, or None.
        path: the file it was read from.
    """

    t: np.ndarray
    T_w_i: np.ndarray
    velocity_w: np.ndarray | None
    gyro_bias: np.ndarray | None
    accel_bias: np.ndarray | None
    path: Path


# --------------------------------------------------------------------------- sensor.yaml
def read_sensor_yaml(path) -> tuple[dict, list[str]]:
    """Read an ASL ``sensor.yaml``: ``(mapping, lines of the file)``.

    The OpenCV directive ``%YAML:1.0`` of the first line (which PyYAML rejects) is
    blanked out, keeping line numbers.

    Raises:
        SequenceFormatError: missing file, YAML syntax error (with its line) or a
            document that is not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "sensor.yaml not found")
    try:
        data, size = read_limited(path, MAX_TEXT_BYTES)
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read: {exc.strerror or exc}") from None
    if data is None:
        raise SequenceFormatError(path, too_large(size, MAX_TEXT_BYTES, "a sensor.yaml"))
    lines = data.decode("utf-8", errors="replace").splitlines()
    text = "\n".join("" if i == 0 and ln.startswith("%YAML:") else ln for i, ln in enumerate(lines))
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SequenceFormatError(path, f"invalid YAML: {problem}", None if mark is None else mark.line + 1) from None
    if not isinstance(data, dict):
        raise SequenceFormatError(path, "expected a YAML mapping of keys to values")
    return data, lines


def _key_line(lines: list[str], key: str) -> int | None:
    """1-based line where ``key:`` starts a line (top level), or None."""
    pat = re.compile(rf"^{re.escape(key)}\s*:")
    return next((i for i, ln in enumerate(lines, 1) if pat.match(ln)), None)


def _numbers(value, n: int | tuple[int, ...], path: Path, lines: list[str], key: str) -> np.ndarray:
    """``value`` as a float array of one of the lengths ``n``, else an error at ``key``'s line."""
    sizes = (n,) if isinstance(n, int) else n
    floats = [yaml_float(v) for v in value] if isinstance(value, list) else None
    if floats is None or len(floats) not in sizes or any(f is None for f in floats):
        want = " or ".join(str(s) for s in sizes)
        raise SequenceFormatError(path, f"{key} must be a list of {want} finite numbers, got {value!r}",
                                  _key_line(lines, key))
    return np.asarray(floats, dtype=np.float64)


def _require(data: dict, key: str, path: Path):
    if key not in data:
        raise SequenceFormatError(path, f"missing key {key!r}")
    return data[key]


def _positive(data: dict, key: str, path: Path, lines: list[str]) -> float:
    v = yaml_float(_require(data, key, path))
    if v is None or v <= 0:
        raise SequenceFormatError(path, f"{key} must be a positive number, got {data[key]!r}", _key_line(lines, key))
    return v


def parse_T_BS(data: dict, path, lines: list[str], *, required: bool = True) -> np.ndarray:
    """The (4, 4) sensor-to-body transform ``T_BS`` (``{rows: 4, cols: 4, data: [16]}``).

    Absent and not ``required``: identity. Raises SequenceFormatError (file and line of
    ``T_BS``) when it is malformed or not a rigid transform.
    """
    path = Path(path)
    if "T_BS" not in data:
        if required:
            raise SequenceFormatError(path, "missing key 'T_BS' (sensor-to-body transform)")
        return np.eye(4)
    block = data["T_BS"]
    line = _key_line(lines, "T_BS")
    if not isinstance(block, dict) or "data" not in block:
        raise SequenceFormatError(path, "T_BS must be a mapping with rows: 4, cols: 4 and data: [16 numbers]", line)
    if block.get("rows", 4) != 4 or block.get("cols", 4) != 4:
        raise SequenceFormatError(path, f"T_BS must be 4 x 4, got {block.get('rows')} x {block.get('cols')}", line)
    values = [yaml_float(v) for v in block["data"]] if isinstance(block["data"], list) else []
    if len(values) != 16 or any(v is None for v in values):
        raise SequenceFormatError(path, "T_BS data must be 16 finite numbers (row-major 4 x 4)", line)
    try:
        return check_transform("T_BS", np.asarray(values, dtype=np.float64).reshape(4, 4))
    except InputError as exc:
        raise SequenceFormatError(path, str(exc), line) from None


def parse_camera_yaml(path) -> tuple[Camera, np.ndarray]:
    """``(Camera, T_B_C (4, 4) camera-to-body)`` from an ASL camera ``sensor.yaml``."""
    path = Path(path)
    data, lines = read_sensor_yaml(path)
    T_B_C = parse_T_BS(data, path, lines)
    size = _numbers(_require(data, "resolution", path), 2, path, lines, "resolution")
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise SequenceFormatError(path, f"resolution must be two positive integers, got {size.tolist()}",
                                  _key_line(lines, "resolution"))
    fu, fv, cu, cv = _numbers(_require(data, "intrinsics", path), 4, path, lines, "intrinsics")
    model_name = data.get("camera_model", "pinhole")
    if model_name != "pinhole":
        raise SequenceFormatError(path, f"camera_model {model_name!r} is not supported (only 'pinhole')",
                                  _key_line(lines, "camera_model"))
    dist_name = str(data.get("distortion_model", "none")).lower()
    if dist_name not in DISTORTION_MODEL_NAMES:
        raise SequenceFormatError(
            path, f"distortion_model {data.get('distortion_model')!r} is not supported; valid: "
                  f"{', '.join(sorted(DISTORTION_MODEL_NAMES))}", _key_line(lines, "distortion_model"))
    model = DISTORTION_MODEL_NAMES[dist_name]
    coeffs = data.get("distortion_coefficients", [])
    sizes = (0, 4) if model == "equidistant" else (0, 4, 5, 8)
    dist = _numbers(coeffs, sizes, path, lines, "distortion_coefficients") if coeffs else np.zeros(0)
    try:
        camera = Camera(int(size[0]), int(size[1]), float(fu), float(fv), float(cu), float(cv),
                        tuple(float(d) for d in dist), model)
    except InputError as exc:
        raise SequenceFormatError(path, str(exc), _key_line(lines, "intrinsics")) from None
    return camera, T_B_C


# --------------------------------------------------------------------------- data.csv
def _timestamps_ns(table: TextTable) -> np.ndarray:
    """(N,) int64 nanoseconds of the first column, strictly increasing (errors name the line)."""
    t_ns = np.empty(len(table), dtype=np.int64)
    for i, fields in enumerate(table.rows):
        try:
            t_ns[i] = int(fields[0])
        except ValueError:
            raise table.error(i, f"timestamp {fields[0]!r} is not an integer number of nanoseconds") from None
    bad = np.flatnonzero(np.diff(t_ns) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise table.error(i, f"timestamps must be strictly increasing ({t_ns[i]} ns after {t_ns[i - 1]} ns)")
    return t_ns


def read_asl_table(path, ncols: int | tuple[int, ...], what: str,
                   layout: str) -> tuple[np.ndarray, np.ndarray, TextTable]:
    """Numeric ASL csv ``t_ns, v1, ...``: ``(t_ns (N,) int64, values (N, k) float64, table)``.

    ``ncols`` is the accepted column count (int or tuple of ints, timestamp included);
    all rows must have the same count. Timestamps must be strictly increasing integers.
    ``what`` / ``layout`` name the table and its columns in messages.
    """
    sizes = (ncols,) if isinstance(ncols, int) else tuple(ncols)
    table = read_text_table(path, what, layout=layout, delimiter=",")
    width = len(table.rows[0])
    for i, fields in enumerate(table.rows):
        if len(fields) not in sizes or len(fields) != width:
            want = " or ".join(str(s) for s in sizes) if width not in sizes else str(width)
            raise table.error(i, f"expected {want} comma-separated columns ({layout}), got {len(fields)}")
    values = table.floats(slice(1, None))
    return _timestamps_ns(table), values, table


def read_asl_images_csv(path) -> tuple[np.ndarray, list[str], TextTable]:
    """Camera ``data.csv`` ``t_ns,filename``: ``(t_ns (N,) int64, file names, table)``."""
    table = read_text_table(path, "images", layout="timestamp [ns],filename", delimiter=",", columns=2)
    for i, fields in enumerate(table.rows):
        if not fields[1]:
            raise table.error(i, "empty file name")
    return _timestamps_ns(table), table.column(1), table


def read_asl_image(path, camera: Camera | None = None) -> np.ndarray:
    """An ASL image as ``(H, W, 3)`` uint8 RGB: grey is repeated into 3 channels, 16-bit
    images are scaled to 8 bits (``round(v / 257)``), BGR(A) files become RGB.

    Raises:
        SequenceFormatError: missing/undecodable file or a size other than ``camera``'s.
    """
    path = Path(path)
    data = read_image_bytes(path)
    expected = None if camera is None else (camera.width, camera.height)
    image = decode_image(data, cv2.IMREAD_UNCHANGED, path, expected_size=expected)  # size checked first
    if image.dtype == np.uint16:
        image = np.round(image / 257.0).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise SequenceFormatError(path, f"unsupported image type {image.dtype} (8- or 16-bit expected)")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    else:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if camera is not None and image.shape[:2] != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"image is {image.shape[1]}x{image.shape[0]} but sensor.yaml says {camera.width}x{camera.height}")
    return np.ascontiguousarray(image)


# --------------------------------------------------------------------------- IMU and ground truth
def read_asl_imu(folder, T_c_b) -> ImuData:
    """IMU samples and noise model of ``folder`` (``data.csv`` + ``sensor.yaml``).

    Args:
        folder: the ``imu0`` folder.
        T_c_b: (4, 4) body-to-camera transform (``T_BS_cam^-1``); ``T_c_i = T_c_b T_BS_imu``.
    """
    folder = Path(folder)
    yaml_path = folder / "sensor.yaml"
    data, lines = read_sensor_yaml(yaml_path)
    T_B_I = parse_T_BS(data, yaml_path, lines, required=False)
    noise = {name: _positive(data, key, yaml_path, lines) for name, key in _IMU_NOISE_KEYS.items()}
    t_ns, values, table = read_asl_table(folder / "data.csv", 7, "IMU", "timestamp [ns], w_x, w_y, w_z, a_x, a_y, a_z")
    problem = imu_sample_problem(values[:, :3], values[:, 3:6])
    if problem is not None:
        raise table.error(problem[0], problem[1])
    return ImuData(t_ns / 1e9, values[:, :3].copy(), values[:, 3:6].copy(), T_c_b @ T_B_I,
                   gravity_w=ASL_GRAVITY_W, **noise)


def read_asl_ground_truth(folder, T_B_I) -> AslGroundTruth:
    """Ground truth of ``folder`` (``data.csv`` with 8 or 17 columns, optional ``sensor.yaml``).

    Args:
        folder: ``state_groundtruth_estimate0`` (or ``mocap0``).
        T_B_I: (4, 4) IMU-to-body transform (identity without an IMU).
    """
    folder = Path(folder)
    csv = folder / "data.csv"
    T_B_S = np.eye(4)
    if (folder / "sensor.yaml").is_file():
        data, lines = read_sensor_yaml(folder / "sensor.yaml")
        T_B_S = parse_T_BS(data, folder / "sensor.yaml", lines, required=False)
    t_ns, v, table = read_asl_table(csv, (8, 17), "ground truth",
                                    "timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, v, b_w, b_a]")
    table.check_positions(v[:, :3])
    q_wxyz = v[:, 3:7]
    norms = np.linalg.norm(q_wxyz, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        raise table.error(int(bad[0]), f"quaternion norm {norms[bad[0]]:.4f} is not 1")
    T_w_s = np.tile(np.eye(4), (len(t_ns), 1, 1))
    T_w_s[:, :3, :3] = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]] / norms[:, None]).as_matrix()
    T_w_s[:, :3, 3] = v[:, :3]
    T_s_i = invert_transform(T_B_S) @ T_B_I
    velocity = gyro_bias = accel_bias = None
    if v.shape[1] == 16:
        gyro_bias, accel_bias = v[:, 10:13].copy(), v[:, 13:16].copy()
        if np.linalg.norm(T_s_i[:3, 3]) <= SAME_ORIGIN_TOLERANCE_M:
            velocity = v[:, 7:10].copy()
    return AslGroundTruth(t_ns / 1e9, T_w_s @ T_s_i, velocity, gyro_bias, accel_bias, csv)


# --------------------------------------------------------------------------- the sequence
def asl_root(path) -> Path | None:
    """The ``mav0`` folder of ``path`` (``path/mav0``, or ``path`` itself when it is one), else None."""
    path = Path(path)
    if (path / "mav0").is_dir():
        return path / "mav0"
    if path.name == "mav0" and path.is_dir():
        return path
    return None


class AslSequence(Sequence):
    """An EuRoC / TUM-VI sequence in the ASL layout (see the module docstring).

    Attributes:
        ground_truth: :class:`AslGroundTruth` (IMU frame) or None.
        T_B_C: (4, 4) camera-to-body transform of ``cam0``.
    """

    format_name = "asl"
    imu_missing_reason = "the ASL folder has no mav0/imu0"

    def __init__(self, path, settings: AslSettings = AslSettings()):
        path = Path(path)
        mav0 = asl_root(path)
        if mav0 is None:
            raise InputError(f"{path}: no mav0/ folder (not an ASL / EuRoC sequence)")
        self.settings = settings
        cam_dir = mav0 / "cam0"
        camera, self.T_B_C = parse_camera_yaml(cam_dir / "sensor.yaml")
        t_ns, names, table = read_asl_images_csv(cam_dir / "data.csv")
        for i, name in enumerate(names):
            if not stays_inside(name):
                raise table.error(i, f"image {name!r} points outside the data folder")
            if not (cam_dir / "data" / name).is_file():
                raise table.error(i, f"image {('data/' + name)!r} not found")
        self._t = t_ns / 1e9
        self._images = [cam_dir / "data" / n for n in names]

        T_c_b = invert_transform(self.T_B_C)
        imu = None
        T_B_I = np.eye(4)
        if (mav0 / "imu0").is_dir():
            imu = read_asl_imu(mav0 / "imu0", T_c_b)
            T_B_I = self.T_B_C @ imu.T_c_i
        self.ground_truth = None
        for name in _GT_FOLDERS:
            if (mav0 / name).is_dir():
                self.ground_truth = read_asl_ground_truth(mav0 / name, T_B_I)
                break
        self._T_w_c = self._velocity = None
        if self.ground_truth is not None:
            gt = self.ground_truth
            T_w_i, ok = interpolate_poses(self._t, gt.t, gt.T_w_i, 0.5 * settings.max_pose_gap_s, bracketed_only=True)
            T_i_c = invert_transform(T_B_I) @ self.T_B_C
            self._T_w_c = [T @ T_i_c if k else None for T, k in zip(T_w_i, ok)]
            if gt.velocity_w is not None:
                vel = np.stack([np.interp(self._t, gt.t, gt.velocity_w[:, k]) for k in range(3)], 1)
                self._velocity = [v if k else None for v, k in zip(vel, ok)]
        name = path.resolve().parent.name if mav0 == path else path.name
        super().__init__(path, name, camera, imu)

    def __len__(self) -> int:
        return len(self._images)

    @property
    def has_gt_depth(self) -> bool:
        return False

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) image timestamps, seconds."""
        return self._t.copy()

    @property
    def n_posed(self) -> int:
        """Number of frames with a ground-truth pose."""
        return 0 if self._T_w_c is None else sum(T is not None for T in self._T_w_c)

    def frame(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(index)
        T = None if self._T_w_c is None else self._T_w_c[index]
        vel = None if self._velocity is None else self._velocity[index]
        return Frame(
            index=index,
            timestamp=float(self._t[index]),
            stem=self._images[index].stem,
            camera=self.camera,
            T_w_c=None if T is None else T.copy(),
            load_image=partial(read_asl_image, self._images[index], self.camera),
            velocity_w=None if vel is None else vel.copy(),
        )


def detect_asl(path) -> bool:
    """True for a folder holding ``mav0/`` (or a ``mav0`` folder) with a ``cam0`` folder."""
    mav0 = asl_root(path)
    return mav0 is not None and (mav0 / "cam0").is_dir()


FORMAT = SequenceFormat(
    "asl", detect_asl, AslSequence,
    "EuRoC / TUM-VI ASL layout (mav0/cam0, imu0, state_groundtruth_estimate0; docs/datasets.md)",
)

__all__ = [
    "ASL_GRAVITY_W", "FORMAT", "AslGroundTruth", "AslSequence", "AslSettings", "asl_root", "detect_asl",
    "parse_T_BS",
    "parse_camera_yaml", "read_asl_ground_truth", "read_asl_image", "read_asl_images_csv", "read_asl_imu",
    "read_asl_table", "read_sensor_yaml",
]
