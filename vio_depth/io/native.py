"""The native vio-depth sequence format, reader side: a folder with ``sequence.json`` (docs/sequence_format.md).

Layout (paths relative to the folder, named in ``sequence.json``)::

    sequence.json      format version, name, camera, file names, IMU block, depth, disparity
    frames.txt         "timestamp image_path" per line (seconds, relative path)
    poses.txt          TUM trajectory "t tx ty tz qx qy qz qw", camera-to-world, metres
                       (optional when an IMU block is present: then only ``--poses vio`` runs)
    imu.txt            optional "t gx gy gz ax ay az" (s, rad/s, m/s^2), >= 100 Hz
    depth/<stem>.png   optional 16-bit ground-truth depth, metres * 256, 0 = invalid
    disparity/<stem>.npy  optional float32 (H, W) affine-invariant disparity, or a
                       {"kind": "simulated"} block: SIMULATED from the GT depth at load time

:class:`NativeSequence` parses the small text files eagerly and validates them; images and
depth are read lazily by each :class:`~vio_depth.frame.Frame`'s loaders; the disparity the
folder carries is declared as a :class:`~vio_depth.disparity.DisparitySpec` (the disparity
stage reads or simulates it). The writer is :mod:`vio_depth.io.native_writer`.
"""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, SequenceFormatError, SettingsError
from vio_core.limits import LimitError, read_json_file

from ..disparity import DisparityKind, DisparitySimulation, DisparitySpec
from ..frame import Frame, ImuData, imu_calibration_problem, imu_sample_problem
from .base import Sequence, SequenceFormat
from .depth_png import DEPTH_PNG_SCALE, read_depth_png
from .images import read_rgb_image
from .tables import read_text_table, read_tum_trajectory, stays_inside

#: value of the "format" key of sequence.json
FORMAT_TAG = "vio-depth-sequence"
#: the only format version this module reads and writes
FORMAT_VERSION = 1
#: a frame takes the pose whose timestamp is within this many seconds of its own
POSE_TIME_TOLERANCE_S = 1e-3
#: imu.txt must have a median sample spacing of at most 1 / this (Hz)
MIN_IMU_RATE_HZ = 100.0

_TOP_KEYS = {"format", "version", "name", "camera", "frames", "poses", "imu", "depth", "disparity", "metadata"}
_CAMERA_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "dist", "model"}
_IMU_KEYS = {"file", "T_c_i", "gyro_noise_density", "accel_noise_density", "gyro_bias_random_walk",
             "accel_bias_random_walk", "gravity_w", "rate_hz", "simulation"}
_DEPTH_KEYS = {"folder", "scale"}


# --------------------------------------------------------------------------- text files
def read_frames_txt(path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Parse a frames list: ``(timestamps (N,) seconds, image paths, line numbers (N,))``.

    Each non-comment line is ``timestamp image_path`` (the path relative to the sequence
    folder, without spaces). Timestamps must be strictly increasing.
    """
    table = read_text_table(path, "frames", layout="timestamp image_path", columns=2)
    t = table.floats(slice(0, 1), what="timestamp")[:, 0]
    table.check_increasing(t)
    return t, table.column(1), np.asarray(table.lines, dtype=np.int64)


def read_imu_txt(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse ``t gx gy gz ax ay az`` per line: ``(t (M,) s, gyro (M, 3) rad/s, accel (M, 3) m/s^2)``.

    Raises:
        SequenceFormatError: bad columns/values, timestamps not strictly increasing, a
            sample beyond :data:`~vio_depth.frame.MAX_GYRO_RAD_S` / ``MAX_ACCEL_M_S2``, or a
            median sample rate below MIN_IMU_RATE_HZ.
    """
    table = read_text_table(path, "IMU", layout="t gx gy gz ax ay az", columns=7)
    rows = table.floats()
    table.check_increasing(rows[:, 0])
    problem = imu_sample_problem(rows[:, 1:4], rows[:, 4:7])
    if problem is not None:
        raise table.error(problem[0], problem[1])
    if len(rows) > 1:
        rate = 1.0 / float(np.median(np.diff(rows[:, 0])))
        if rate < MIN_IMU_RATE_HZ * (1 - 1e-6):
            raise table.error(None, f"IMU rate {rate:.1f} Hz is below the required {MIN_IMU_RATE_HZ:.0f} Hz")
    return rows[:, 0].copy(), rows[:, 1:4].copy(), rows[:, 4:7].copy()


def _load_depth(path: Path, camera: Camera, scale: float) -> np.ndarray:
    depth = read_depth_png(path, scale)
    if depth.shape != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"depth is {depth.shape[1]}x{depth.shape[0]} but the camera is {camera.width}x{camera.height}")
    return depth


# --------------------------------------------------------------------------- sequence.json
def _require(mapping: dict, key: str, path: Path, where: str):
    if key not in mapping:
        raise SequenceFormatError(path, f"missing key {where}{key!r}")
    return mapping[key]


def _check_keys(mapping, allowed: set, path: Path, where: str) -> None:
    if not isinstance(mapping, dict):
        raise SequenceFormatError(path, f"{where or 'top level'} must be a JSON object")
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        raise SequenceFormatError(path, f"unknown key(s) {', '.join(map(repr, unknown))} in "
                                        f"{where or 'top level'}; valid: {', '.join(sorted(allowed))}")


def _number(value, path: Path, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise SequenceFormatError(path, f"{where} must be a finite number, got {value!r}")
    return float(value)


def _relative_file(root: Path, value, path: Path, where: str, line: int | None = None) -> Path:
    """``root / value`` for a relative path that stays inside the sequence folder (no ``..``
    escape; a symbolic link inside the folder may point elsewhere)."""
    if not isinstance(value, str) or not value or Path(value).is_absolute():
        raise SequenceFormatError(path, f"{where} must be a relative path string, got {value!r}", line)
    if not stays_inside(value):
        raise SequenceFormatError(path, f"{where} {value!r} points outside the sequence folder", line)
    return root / value


def _parse_camera(block, path: Path) -> Camera:
    _check_keys(block, _CAMERA_KEYS, path, "camera.")
    vals = {}
    for key in ("width", "height"):
        v = _require(block, key, path, "camera.")
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise SequenceFormatError(path, f"camera.{key} must be a positive integer, got {v!r}")
        vals[key] = v
    for key in ("fx", "fy", "cx", "cy"):
        vals[key] = _number(_require(block, key, path, "camera."), path, f"camera.{key}")
    model = block.get("model", "radtan")
    if model not in ("radtan", "equidistant"):
        raise SequenceFormatError(path, f"camera.model must be 'radtan' or 'equidistant', got {model!r}")
    dist = block.get("dist", [])
    if model == "radtan" and (not isinstance(dist, list) or len(dist) not in (0, 4, 5)):
        raise SequenceFormatError(path, f"camera.dist must be a list of 0, 4 (k1 k2 p1 p2) or 5 (+k3) numbers, got {dist!r}")
    if model == "equidistant" and (not isinstance(dist, list) or len(dist) not in (0, 4)):
        raise SequenceFormatError(path, f"camera.dist of an equidistant camera must be a list of 0 or 4 numbers "
                                        f"(k1 k2 k3 k4), got {dist!r}")
    dist = tuple(_number(d, path, "camera.dist[]") for d in dist)
    try:
        return Camera(vals["width"], vals["height"], vals["fx"], vals["fy"], vals["cx"], vals["cy"], dist, model)
    except InputError as exc:
        raise SequenceFormatError(path, str(exc)) from None


def _parse_T_c_i(value, path: Path) -> np.ndarray:
    arr = None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        pass
    if arr is None or arr.shape not in ((4, 4), (16,)):
        raise SequenceFormatError(path, "imu.T_c_i must be a 4x4 row-major matrix (nested list or 16 numbers)")
    T = arr.reshape(4, 4)
    try:
        return check_transform("imu.T_c_i", T)
    except InputError as exc:
        raise SequenceFormatError(path, str(exc)) from None


def _parse_disparity(block, path: Path) -> DisparitySpec:
    if not isinstance(block, dict):
        raise SequenceFormatError(path, "disparity must be a JSON object")
    kind = _require(block, "kind", path, "disparity.")
    if kind == "files":
        _check_keys(block, {"kind", "folder"}, path, "disparity.")
        folder = _require(block, "folder", path, "disparity.")
        _relative_file(path.parent, folder, path, "disparity.folder")
        return DisparitySpec.files(folder)
    if kind == "simulated":
        _check_keys(block, {"kind", "seed", "model"}, path, "disparity.")
        seed = _require(block, "seed", path, "disparity.")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise SequenceFormatError(path, f"disparity.seed must be a non-negative integer, got {seed!r}")
        model = _require(block, "model", path, "disparity.")
        if not isinstance(model, dict):
            raise SequenceFormatError(path, "disparity.model must be a JSON object")
        try:
            return DisparitySpec.simulated(seed, DisparitySimulation.from_json(model))
        except (InputError, SettingsError, TypeError) as exc:
            raise SequenceFormatError(path, f"disparity.model: {exc}") from None
    raise SequenceFormatError(path, f"disparity.kind must be 'files' or 'simulated', got {kind!r}")


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise SequenceFormatError(path, "sequence.json not found")
    try:
        data = read_json_file(path, what="sequence.json")
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise SequenceFormatError(path, f"invalid JSON: {exc.msg} (column {exc.colno})", exc.lineno) from None
    except UnicodeDecodeError as exc:
        raise SequenceFormatError(path, f"not UTF-8 text: {exc}") from None
    except LimitError as exc:  # larger than vio_core.limits allows, or nested too deeply
        raise SequenceFormatError(path, str(exc)) from None
    if not isinstance(data, dict):
        raise SequenceFormatError(path, "top level must be a JSON object")
    return data


# --------------------------------------------------------------------------- the sequence
class NativeSequence(Sequence):
    """A native-format sequence folder (see docs/sequence_format.md).

    Construction reads and validates ``sequence.json``, the frames list, the poses and the
    IMU samples, and checks that every image file exists; pixels are read only when a
    frame's ``image()``, ``gt_depth()`` or ``disparity()`` is called.

    Attributes:
        timestamps: (N,) seconds of the frames.
        T_w_c: (N, 4, 4) camera-to-world pose of each frame, metres, or None for a sequence
            without poses (allowed only with IMU samples: the ``vio`` pose source needs no poses).
        image_paths: absolute image path of each frame.
        disparity: the :class:`~vio_depth.disparity.DisparitySpec` the folder declares, or None.
    """

    format_name = "native"

    def __init__(self, root):
        root = Path(root)
        json_path = root / "sequence.json"
        meta = _read_json(json_path)
        _check_keys(meta, _TOP_KEYS, json_path, "")
        tag = _require(meta, "format", json_path, "")
        if tag != FORMAT_TAG:
            raise SequenceFormatError(json_path, f"format must be {FORMAT_TAG!r}, got {tag!r}")
        version = _require(meta, "version", json_path, "")
        if version != FORMAT_VERSION:
            raise SequenceFormatError(json_path, f"unknown format version {version!r} (this reader supports {FORMAT_VERSION})")
        name = _require(meta, "name", json_path, "")
        if not isinstance(name, str):
            raise SequenceFormatError(json_path, f"name must be a string, got {name!r}")
        camera = _parse_camera(_require(meta, "camera", json_path, ""), json_path)
        self.metadata = meta.get("metadata", {})

        frames_path = _relative_file(root, _require(meta, "frames", json_path, ""), json_path, "frames")
        poses_path = None
        if meta.get("poses") is not None:
            poses_path = _relative_file(root, meta["poses"], json_path, "poses")
        elif meta.get("imu") is None:
            raise SequenceFormatError(json_path, "missing key 'poses' (it may be left out only when an 'imu' block "
                                                 "is present: then the poses come from --poses vio)")
        t_frames, image_names, frame_lines = read_frames_txt(frames_path)
        self.timestamps = t_frames
        self.image_paths = []
        stems = {}
        for name_i, line in zip(image_names, frame_lines):
            p = _relative_file(root, name_i, frames_path, "image path", int(line))
            if not p.is_file():
                raise SequenceFormatError(frames_path, f"image file {name_i!r} not found", int(line))
            stem = Path(name_i).stem
            if stem in stems:
                raise SequenceFormatError(frames_path, f"image stem {stem!r} repeats line {stems[stem]}", int(line))
            stems[stem] = int(line)
            self.image_paths.append(p)
        self.stems = list(stems)

        self.T_w_c = None
        if poses_path is not None:
            t_poses, T_poses = read_tum_trajectory(poses_path)
            j = np.searchsorted(t_poses, t_frames)
            lo = np.clip(j - 1, 0, len(t_poses) - 1)
            hi = np.clip(j, 0, len(t_poses) - 1)
            j = np.where(np.abs(t_poses[lo] - t_frames) <= np.abs(t_poses[hi] - t_frames), lo, hi)
            gap = np.abs(t_poses[j] - t_frames)
            missing = np.flatnonzero(gap > POSE_TIME_TOLERANCE_S)
            if len(missing):
                i = int(missing[0])
                raise SequenceFormatError(
                    frames_path, f"frame {self.stems[i]!r} (t={t_frames[i]:.6f}) has no pose in {poses_path.name} "
                    f"within {POSE_TIME_TOLERANCE_S * 1e3:.0f} ms", int(frame_lines[i]))
            self.T_w_c = T_poses[j]

        imu = None
        if meta.get("imu") is not None:
            imu = self._parse_imu(meta["imu"], root, json_path)

        self._depth_folder = None
        self._depth_scale = DEPTH_PNG_SCALE
        if meta.get("depth") is not None:
            block = meta["depth"]
            _check_keys(block, _DEPTH_KEYS, json_path, "depth.")
            self._depth_folder = _relative_file(root, _require(block, "folder", json_path, "depth."), json_path, "depth.folder")
            self._depth_scale = _number(block.get("scale", DEPTH_PNG_SCALE), json_path, "depth.scale")
            if self._depth_scale <= 0:
                raise SequenceFormatError(json_path, "depth.scale must be positive")

        disparity = None
        if meta.get("disparity") is not None:
            disparity = _parse_disparity(meta["disparity"], json_path)
            if disparity.kind == DisparityKind.SIMULATED and self._depth_folder is None:
                raise SequenceFormatError(json_path, "simulated disparity needs a depth block (it is computed from GT depth)")
        super().__init__(root, name, camera, imu, disparity)

    @staticmethod
    def _parse_imu(block, root: Path, json_path: Path) -> ImuData:
        _check_keys(block, _IMU_KEYS, json_path, "imu.")
        imu_path = _relative_file(root, _require(block, "file", json_path, "imu."), json_path, "imu.file")
        T_c_i = _parse_T_c_i(_require(block, "T_c_i", json_path, "imu."), json_path)
        noise = {
            "gyro_noise": _number(_require(block, "gyro_noise_density", json_path, "imu."), json_path, "imu.gyro_noise_density"),
            "accel_noise": _number(_require(block, "accel_noise_density", json_path, "imu."), json_path, "imu.accel_noise_density"),
            "gyro_bias_walk": _number(_require(block, "gyro_bias_random_walk", json_path, "imu."), json_path, "imu.gyro_bias_random_walk"),
            "accel_bias_walk": _number(_require(block, "accel_bias_random_walk", json_path, "imu."), json_path, "imu.accel_bias_random_walk"),
        }
        gravity = block.get("gravity_w", [0.0, 0.0, -9.81])
        if not isinstance(gravity, list) or len(gravity) != 3:
            raise SequenceFormatError(json_path, f"imu.gravity_w must be a list of 3 numbers, got {gravity!r}")
        gravity = tuple(_number(g, json_path, "imu.gravity_w[]") for g in gravity)
        problem = imu_calibration_problem(gravity_w=gravity, **noise)
        if problem:
            raise SequenceFormatError(json_path, f"imu.{problem}")
        t, gyro, accel = read_imu_txt(imu_path)
        return ImuData(t, gyro, accel, T_c_i, gravity_w=gravity, **noise)

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def pose_kind(self) -> str:
        """``exact`` for a SIMULATED (rendered) sequence, else ``mocap`` (see :class:`Sequence`)."""
        return "exact" if self.metadata.get("simulated") is True else "mocap"

    @property
    def has_gt_depth(self) -> bool:
        return self._depth_folder is not None

    def frame(self, index: int) -> Frame:
        """Frame ``index`` with lazy loaders (reads no pixels)."""
        if not 0 <= index < len(self):
            raise IndexError(index)
        camera = self.camera
        stem = self.stems[index]
        image_path = self.image_paths[index]
        load_depth = None
        if self._depth_folder is not None:
            load_depth = partial(_load_depth, self._depth_folder / f"{stem}.png", camera, self._depth_scale)
        return Frame(
            index=index,
            timestamp=float(self.timestamps[index]),
            stem=stem,
            camera=camera,
            T_w_c=None if self.T_w_c is None else self.T_w_c[index].copy(),
            load_image=partial(read_rgb_image, image_path, camera),
            load_gt_depth=load_depth,
        )


def detect_native(path) -> bool:
    """True when ``path`` is a folder holding a ``sequence.json``."""
    path = Path(path)
    return path.is_dir() and (path / "sequence.json").is_file()


def open_native(path) -> NativeSequence:
    return NativeSequence(path)


FORMAT = SequenceFormat(
    "native", detect_native, open_native,
    "vio-depth native folder with sequence.json (docs/sequence_format.md)",
)
