"""Kalibr calibration files (``camchain.yaml``, ``imu.yaml``) for any input (``--calib``, ``--imu-calib``).

Kalibr is the calibration robot users have: ``kalibr_calibrate_cameras`` /
``kalibr_calibrate_imu_camera`` write a camera chain (``camchain-imucam-*.yaml``)::

    cam0:
      camera_model: pinhole
      intrinsics: [fu, fv, pu, pv]              # pixels
      distortion_model: radtan                  # or equidistant, none
      distortion_coeffs: [k1, k2, r1, r2]       # equidistant: [k1, k2, k3, k4]
      resolution: [width, height]
      T_cam_imu: [[...4 rows of 4...]]          # IMU-to-camera (maps IMU points into the camera)
      timeshift_cam_imu: 0.0                    # seconds: t_imu = t_cam + timeshift_cam_imu
      rostopic: /cam0/image_raw

and the IMU noise model (``imu.yaml``; the ``imu0:`` level is optional, as in the file
Kalibr takes as input)::

    imu0:
      accelerometer_noise_density: 2.0e-3      # m/s^2/sqrt(Hz)
      accelerometer_random_walk: 3.0e-3        # m/s^3/sqrt(Hz)
      gyroscope_noise_density: 1.7e-4          # rad/s/sqrt(Hz)
      gyroscope_random_walk: 2.0e-5            # rad/s^2/sqrt(Hz)
      rostopic: /imu0
      update_rate: 200.0

These map onto vio-depth's types one to one: ``intrinsics`` / ``distortion_*`` /
``resolution`` -> :class:`~vio_core.camera.Camera` (``radtan`` -> ``"radtan"``,
``equidistant`` -> ``"equidistant"``), ``T_cam_imu`` -> ``ImuData.T_c_i``, the four
densities -> ``ImuData.gyro_noise`` ... ``accel_bias_walk`` (continuous-time, the units the
IMU factors take), and ``timeshift_cam_imu`` moves the IMU samples onto the camera clock
(``t_cam = t_imu - timeshift_cam_imu``). :func:`apply_calibration` applies a calibration
to any opened sequence; the bag loader (:mod:`vio_depth.io.bag`) takes it directly.
Other camera models (``omni``, ``ds``, ``eucm``) and distortion models (``fov``) are refused
with the list of supported ones. :func:`write_camchain` / :func:`write_imu_yaml` write the
same files (read back, they give the same camera and IMU settings).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, SequenceFormatError

from ..frame import Frame, ImuData
from .base import Sequence
from .tables import yaml_float

#: Kalibr distortion model names -> vio_core.Camera models
KALIBR_DISTORTION_MODELS = {"radtan": "radtan", "equidistant": "equidistant", "none": "radtan"}
#: vio_core.Camera model -> Kalibr distortion model name
_KALIBR_NAME = {"radtan": "radtan", "equidistant": "equidistant"}
_IMU_KEYS = {"gyro_noise": "gyroscope_noise_density", "gyro_bias_walk": "gyroscope_random_walk",
             "accel_noise": "accelerometer_noise_density", "accel_bias_walk": "accelerometer_random_walk"}


@dataclass(frozen=True)
class KalibrCamera:
    """One camera of a Kalibr camera chain.

    Attributes:
        name: its key in the file (``cam0``).
        camera: intrinsics, distortion and image size.
        T_c_i: (4, 4) IMU-to-camera transform (``T_cam_imu``), or None (a camera-only calibration).
        timeshift_cam_imu: seconds, ``t_imu = t_cam + timeshift_cam_imu``.
        rostopic: the image topic it was calibrated on, or None.
    """

    name: str
    camera: Camera
    T_c_i: np.ndarray | None = None
    timeshift_cam_imu: float = 0.0
    rostopic: str | None = None


@dataclass(frozen=True)
class KalibrImu:
    """The IMU noise model of a Kalibr ``imu.yaml`` (continuous-time densities).

    Attributes:
        gyro_noise: rad/s/sqrt(Hz). gyro_bias_walk: rad/s^2/sqrt(Hz).
        accel_noise: m/s^2/sqrt(Hz). accel_bias_walk: m/s^3/sqrt(Hz).
        rostopic: the IMU topic, or None. update_rate: Hz, or None (informative).
    """

    gyro_noise: float
    gyro_bias_walk: float
    accel_noise: float
    accel_bias_walk: float
    rostopic: str | None = None
    update_rate: float | None = None


@dataclass(frozen=True)
class Calibration:
    """What ``--calib`` / ``--imu-calib`` give: a camera (with its IMU extrinsic) and/or an IMU noise model."""

    camera: KalibrCamera | None = None
    imu: KalibrImu | None = None

    @property
    def empty(self) -> bool:
        return self.camera is None and self.imu is None


# --------------------------------------------------------------------------- reading
def _load(path) -> tuple[dict, list[str], Path]:
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "calibration file not found")
    text = path.read_text(encoding="utf-8", errors="replace")
    lines = text.splitlines()
    try:
        data = yaml.safe_load("\n".join("" if i == 0 and ln.startswith("%YAML") else ln for i, ln in enumerate(lines)))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SequenceFormatError(path, f"invalid YAML: {problem}", None if mark is None else mark.line + 1) from None
    if not isinstance(data, dict):
        raise SequenceFormatError(path, "expected a YAML mapping (a Kalibr calibration file)")
    return data, lines, path


def _line(lines: list[str], key: str, after: int = 0) -> int | None:
    """1-based line of the first ``key:`` at or after line ``after`` (any indentation), or None."""
    pat = re.compile(rf"^\s*-?\s*{re.escape(key)}\s*:")
    return next((i for i, ln in enumerate(lines, 1) if i > after and pat.match(ln)), None)


class _Block:
    """A mapping of a calibration file with errors that name the file and the key's line."""

    def __init__(self, data: dict, path: Path, lines: list[str], name: str, start: int = 0):
        self.data, self.path, self.lines, self.name, self.start = data, path, lines, name, start

    def error(self, key: str, message: str) -> SequenceFormatError:
        return SequenceFormatError(self.path, f"{self.name}.{key}: {message}" if self.name else f"{key}: {message}",
                                   _line(self.lines, key, self.start))

    def require(self, key: str):
        if key not in self.data:
            where = f"{self.name}: " if self.name else ""
            raise SequenceFormatError(self.path, f"{where}missing key {key!r}", _line(self.lines, self.name or key))
        return self.data[key]

    def numbers(self, key: str, sizes: tuple[int, ...], value=None) -> np.ndarray:
        value = self.require(key) if value is None else value
        floats = [yaml_float(v) for v in value] if isinstance(value, list) else None
        if floats is None or len(floats) not in sizes or any(f is None for f in floats):
            raise self.error(key, f"expected a list of {' or '.join(map(str, sizes))} finite numbers, got {value!r}")
        return np.asarray(floats, dtype=np.float64)

    def positive(self, key: str) -> float:
        v = yaml_float(self.require(key))
        if v is None or v <= 0:
            raise self.error(key, f"must be a positive number, got {self.data[key]!r}")
        return v

    def transform(self, key: str) -> np.ndarray:
        value = self.require(key)
        rows = value if isinstance(value, list) and len(value) == 4 else None
        if rows is None or not all(isinstance(r, list) for r in rows):
            raise self.error(key, "expected 4 rows of 4 numbers")
        T = np.stack([self.numbers(key, (4,), r) for r in rows])
        try:
            return check_transform(key, T)
        except InputError as exc:
            raise self.error(key, str(exc)) from None


def _read_camera(block: _Block) -> KalibrCamera:
    model = str(block.data.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise block.error("camera_model", f"{model!r} is not supported (only 'pinhole')")
    dist_name = str(block.data.get("distortion_model", "none")).lower()
    if dist_name not in KALIBR_DISTORTION_MODELS:
        raise block.error("distortion_model", f"{dist_name!r} is not supported; valid: "
                                              f"{', '.join(sorted(KALIBR_DISTORTION_MODELS))}")
    cam_model = KALIBR_DISTORTION_MODELS[dist_name]
    fu, fv, pu, pv = block.numbers("intrinsics", (4,))
    size = block.numbers("resolution", (2,))
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise block.error("resolution", f"must be two positive integers, got {size.tolist()}")
    coeffs = block.data.get("distortion_coeffs", [])
    sizes = (0, 4) if cam_model == "equidistant" else (0, 4, 5, 8)
    dist = block.numbers("distortion_coeffs", sizes, coeffs) if coeffs else np.zeros(0)
    if dist_name == "none" and np.any(dist != 0):
        raise block.error("distortion_coeffs", "distortion_model none takes no (or zero) coefficients")
    try:
        camera = Camera(int(size[0]), int(size[1]), float(fu), float(fv), float(pu), float(pv),
                        tuple(float(d) for d in dist), cam_model)
    except InputError as exc:
        raise block.error("intrinsics", str(exc)) from None
    T_c_i = block.transform("T_cam_imu") if "T_cam_imu" in block.data else None
    shift = 0.0
    if "timeshift_cam_imu" in block.data:
        shift = yaml_float(block.data["timeshift_cam_imu"])
        if shift is None:
            raise block.error("timeshift_cam_imu",
                              f"must be a number of seconds, got {block.data['timeshift_cam_imu']!r}")
    topic = block.data.get("rostopic")
    return KalibrCamera(block.name, camera, T_c_i, shift, None if topic is None else str(topic))


def read_camchain(path, topic: str | None = None) -> KalibrCamera:
    """The camera of a Kalibr camera chain: the one calibrated on ``topic`` when given
    (``rostopic``), else the first (``cam0``).

    Raises:
        SequenceFormatError: missing file or key, malformed values (file and line named),
            an unsupported camera or distortion model, or no camera on ``topic``.
    """
    data, lines, path = _load(path)
    cams = sorted((k for k in data if re.fullmatch(r"cam\d+", str(k))), key=lambda k: int(str(k)[3:]))
    if not cams:
        raise SequenceFormatError(path, "no camera (cam0, cam1, ...): not a Kalibr camchain.yaml")
    blocks = []
    for name in cams:
        if not isinstance(data[name], dict):
            raise SequenceFormatError(path, f"{name}: expected a mapping of calibration keys", _line(lines, name))
        blocks.append(_Block(data[name], path, lines, name, (_line(lines, name) or 1) - 1))
    chosen = blocks[0]
    if topic is not None and len(blocks) > 1:
        matching = [b for b in blocks if b.data.get("rostopic") == topic]
        if not matching:
            have = ", ".join(f"{b.name} ({b.data.get('rostopic', 'no rostopic')})" for b in blocks)
            raise SequenceFormatError(path, f"no camera calibrated on {topic}: {have}")
        chosen = matching[0]
    return _read_camera(chosen)


def read_imu_yaml(path) -> KalibrImu:
    """The IMU noise model of a Kalibr ``imu.yaml`` (``imu0:`` block or top-level keys).

    Raises:
        SequenceFormatError: missing file or key, or a density that is not a positive number.
    """
    data, lines, path = _load(path)
    name = ""
    if "imu0" in data:
        if not isinstance(data["imu0"], dict):
            raise SequenceFormatError(path, "imu0: expected a mapping of noise keys", _line(lines, "imu0"))
        data, name = data["imu0"], "imu0"
    block = _Block(data, path, lines, name, (_line(lines, name) or 1) - 1 if name else 0)
    noise = {field: block.positive(key) for field, key in _IMU_KEYS.items()}
    rate = yaml_float(data.get("update_rate")) if "update_rate" in data else None
    topic = data.get("rostopic")
    return KalibrImu(**noise, rostopic=None if topic is None else str(topic), update_rate=rate)


def read_calibration(camchain=None, imu_yaml=None, topic: str | None = None) -> Calibration:
    """``--calib`` and ``--imu-calib`` as one :class:`Calibration` (either may be None)."""
    return Calibration(None if camchain is None else read_camchain(camchain, topic),
                       None if imu_yaml is None else read_imu_yaml(imu_yaml))


# --------------------------------------------------------------------------- writing
def _num(v: float) -> str:
    """A float that YAML 1.1 reads back as the same float (``2e-05`` -> ``2.0e-05``)."""
    text = repr(float(v))
    if "e" in text and "." not in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    return text


def _list(values) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def write_camchain(path, camera: Camera, T_c_i=None, *, timeshift_cam_imu: float = 0.0,
                   rostopic: str | None = None, name: str = "cam0") -> Path:
    """Write a one-camera Kalibr ``camchain.yaml`` (values exact: read back they are equal).

    Args:
        camera: intrinsics, distortion and size.
        T_c_i: (4, 4) IMU-to-camera transform (``T_cam_imu``), or None.
        timeshift_cam_imu: seconds, ``t_imu = t_cam + timeshift_cam_imu``.
    """
    out = [f"{name}:"]
    if T_c_i is not None:
        T = check_transform("T_c_i", T_c_i)
        out.append("  T_cam_imu:")
        out += [f"  - {_list(row)}" for row in T]
    out += ["  cam_overlaps: []", "  camera_model: pinhole",
            f"  distortion_coeffs: {_list(camera.dist) if camera.dist else '[]'}",
            f"  distortion_model: {_KALIBR_NAME[camera.model] if camera.dist else 'none'}",
            f"  intrinsics: {_list([camera.fx, camera.fy, camera.cx, camera.cy])}",
            f"  resolution: [{camera.width}, {camera.height}]"]
    if rostopic:
        out.append(f"  rostopic: {rostopic}")
    out.append(f"  timeshift_cam_imu: {_num(timeshift_cam_imu)}")
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")
    return Path(path)


def write_imu_yaml(path, imu: ImuData | KalibrImu, *, rostopic: str | None = None,
                   update_rate: float | None = None) -> Path:
    """Write a Kalibr ``imu.yaml`` with the noise model of ``imu`` (exact values)."""
    out = ["imu0:", "  T_i_b:"] + [f"  - {_list(r)}" for r in np.eye(4)]
    out += [f"  accelerometer_noise_density: {_num(imu.accel_noise)}",
            f"  accelerometer_random_walk: {_num(imu.accel_bias_walk)}",
            f"  gyroscope_noise_density: {_num(imu.gyro_noise)}",
            f"  gyroscope_random_walk: {_num(imu.gyro_bias_walk)}", "  model: calibrated"]
    if rostopic:
        out.append(f"  rostopic: {rostopic}")
    out.append("  time_offset: 0.0")
    if update_rate:
        out.append(f"  update_rate: {_num(update_rate)}")
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")
    return Path(path)


# --------------------------------------------------------------------------- applying
def calibrated_imu(imu: ImuData, calibration: Calibration) -> ImuData:
    """``imu`` with the calibration's ``T_c_i``, time shift and noise model where it has them."""
    cam, noise = calibration.camera, calibration.imu
    t, T_c_i = imu.t, imu.T_c_i
    if cam is not None and cam.T_c_i is not None:
        T_c_i = cam.T_c_i
    if cam is not None and cam.timeshift_cam_imu != 0.0:
        t = imu.t - cam.timeshift_cam_imu
    densities = {} if noise is None else {k: getattr(noise, k) for k in _IMU_KEYS}
    return replace(imu, t=t, T_c_i=T_c_i, **densities)


class CalibratedSequence(Sequence):
    """A sequence seen through a Kalibr calibration: its camera, IMU extrinsic, time shift and
    noise model replace the loader's. Poses, depth, disparity and images are the loader's
    (the ground-truth camera poses stay those the loader computed from its own extrinsics)."""

    def __init__(self, inner: Sequence, calibration: Calibration):
        self.inner = inner
        self.calibration = calibration
        camera = inner.camera
        if calibration.camera is not None:
            camera = calibration.camera.camera
            if (camera.width, camera.height) != (inner.camera.width, inner.camera.height):
                raise InputError(f"--calib: {calibration.camera.name} is {camera.width}x{camera.height} but the "
                                 f"images of {inner.root} are {inner.camera.width}x{inner.camera.height}")
        imu = inner.imu
        if imu is not None:
            imu = calibrated_imu(imu, calibration)
        elif calibration.imu is not None:
            raise InputError(f"--imu-calib: {inner.root} has no IMU samples to apply it to "
                             f"({inner.imu_missing_reason or 'no IMU'})")
        super().__init__(inner.root, inner.name, camera, imu, inner.disparity)
        self.format_name = inner.format_name
        self.imu_missing_reason = inner.imu_missing_reason
        self.pose_kind = inner.pose_kind

    def __len__(self) -> int:
        return len(self.inner)

    @property
    def has_gt_depth(self) -> bool:
        return self.inner.has_gt_depth

    def frame(self, index: int) -> Frame:
        return replace(self.inner.frame(index), camera=self.camera)


def apply_calibration(sequence: Sequence, calibration: Calibration) -> Sequence:
    """``sequence`` with ``calibration`` applied (itself when the calibration is empty)."""
    return sequence if calibration.empty else CalibratedSequence(sequence, calibration)


__all__ = [
    "Calibration", "CalibratedSequence", "KALIBR_DISTORTION_MODELS", "KalibrCamera", "KalibrImu", "apply_calibration",
    "calibrated_imu", "read_calibration", "read_camchain", "read_imu_yaml", "write_camchain", "write_imu_yaml",
]
