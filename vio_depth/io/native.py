"""The native vio-depth sequence format: a folder with ``sequence.json`` (docs/sequence_format.md).

Layout (paths relative to the folder, named in ``sequence.json``)::

    sequence.json      format version, name, camera, file names, IMU block, depth, disparity
    frames.txt         "timestamp image_path" per line (seconds, relative path)
    poses.txt          TUM trajectory "t tx ty tz qx qy qz qw", camera-to-world, metres
    imu.txt            optional "t gx gy gz ax ay az" (s, rad/s, m/s^2), >= 100 Hz
    depth/<stem>.png   optional 16-bit ground-truth depth, metres * 256, 0 = invalid
    disparity/<stem>.npy  optional float32 (H, W) affine-invariant disparity, or a
                       {"kind": "simulated"} block: SIMULATED from the GT depth at load time

:class:`NativeSequence` parses the small text files eagerly and validates them; images,
depth and disparity are read lazily by each :class:`~vio_depth.types.Frame`'s loaders.
:class:`NativeSequenceWriter` / :func:`write_native_sequence` write the format.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import transform_to_tum
from ..types import Frame, ImuData
from .base import Sequence, SequenceFormat, register_format
from .depth_png import DEPTH_PNG_SCALE, read_depth_png, write_depth_png

#: value of the "format" key of sequence.json
FORMAT_TAG = "vio-depth-sequence"
#: the only format version this module reads and writes
FORMAT_VERSION = 1
#: a frame takes the pose whose timestamp is within this many seconds of its own
POSE_TIME_TOLERANCE_S = 1e-3
#: quaternions in poses.txt must have |norm - 1| below this
QUATERNION_NORM_TOLERANCE = 1e-3
#: imu.txt must have a median sample spacing of at most 1 / this (Hz)
MIN_IMU_RATE_HZ = 100.0

_TOP_KEYS = {"format", "version", "name", "camera", "frames", "poses", "imu", "depth", "disparity", "metadata"}
_CAMERA_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "dist"}
_IMU_KEYS = {"file", "T_c_i", "gyro_noise_density", "accel_noise_density", "gyro_bias_random_walk",
             "accel_bias_random_walk", "gravity_w", "rate_hz", "simulation"}
_DEPTH_KEYS = {"folder", "scale"}


# --------------------------------------------------------------------------- text tables
def _read_numeric_table(path: Path, ncols: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a whitespace-separated numeric file: ``(values (N, ncols) float64, lines (N,))``.

    Blank lines and lines starting with ``#`` are skipped; ``lines`` are 1-based numbers.
    """
    if not path.is_file():
        raise SequenceFormatError(path, f"{what} file not found")
    rows, lines = [], []
    with open(path, encoding="utf-8") as fh:
        for lineno, raw in enumerate(fh, start=1):
            text = raw.strip()
            if not text or text.startswith("#"):
                continue
            parts = text.split()
            if len(parts) != ncols:
                raise SequenceFormatError(path, f"expected {ncols} columns ({what}), got {len(parts)}", lineno)
            try:
                values = [float(p) for p in parts]
            except ValueError:
                raise SequenceFormatError(path, f"non-numeric value in {text!r}", lineno) from None
            if not all(np.isfinite(values)):
                raise SequenceFormatError(path, f"non-finite value in {text!r}", lineno)
            rows.append(values)
            lines.append(lineno)
    if not rows:
        raise SequenceFormatError(path, f"no {what} rows")
    return np.asarray(rows, dtype=np.float64), np.asarray(lines, dtype=np.int64)


def _check_increasing(path: Path, t: np.ndarray, lines: np.ndarray) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise SequenceFormatError(
            path, f"timestamps must be strictly increasing ({t[i]:.6f} after {t[i - 1]:.6f})", int(lines[i]))


def read_frames_txt(path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Parse a frames list: ``(timestamps (N,) seconds, image paths, line numbers (N,))``.

    Each non-comment line is ``timestamp image_path`` (the path relative to the sequence
    folder, without spaces). Timestamps must be strictly increasing.
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "frames file not found")
    times, names, lines = [], [], []
    with open(path, encoding="utf-8") as fh:
        for lineno, raw in enumerate(fh, start=1):
            text = raw.strip()
            if not text or text.startswith("#"):
                continue
            parts = text.split()
            if len(parts) != 2:
                raise SequenceFormatError(path, f"expected 2 columns (timestamp image_path), got {len(parts)}", lineno)
            try:
                t = float(parts[0])
            except ValueError:
                raise SequenceFormatError(path, f"non-numeric timestamp {parts[0]!r}", lineno) from None
            if not np.isfinite(t):
                raise SequenceFormatError(path, f"non-finite timestamp {parts[0]!r}", lineno)
            times.append(t)
            names.append(parts[1])
            lines.append(lineno)
    if not times:
        raise SequenceFormatError(path, "no frames listed")
    t = np.asarray(times)
    ln = np.asarray(lines, dtype=np.int64)
    _check_increasing(path, t, ln)
    return t, names, ln


def read_tum_trajectory(path) -> tuple[np.ndarray, np.ndarray]:
    """Parse a TUM trajectory ``t tx ty tz qx qy qz qw`` per line.

    Returns:
        t: (N,) seconds, strictly increasing.
        T_w_c: (N, 4, 4) camera-to-world transforms, metres.

    Raises:
        SequenceFormatError: wrong column count, non-numeric values, a quaternion whose
            norm differs from 1 by more than QUATERNION_NORM_TOLERANCE, or timestamps not
            strictly increasing (names the file and line).
    """
    from scipy.spatial.transform import Rotation

    path = Path(path)
    rows, lines = _read_numeric_table(path, 8, "t tx ty tz qx qy qz qw")
    norms = np.linalg.norm(rows[:, 4:8], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        i = int(bad[0])
        raise SequenceFormatError(path, f"quaternion norm {norms[i]:.6f} is not 1", int(lines[i]))
    _check_increasing(path, rows[:, 0], lines)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8] / norms[:, None]).as_matrix()
    T[:, :3, 3] = rows[:, 1:4]
    return rows[:, 0].copy(), T


def read_imu_txt(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse ``t gx gy gz ax ay az`` per line: ``(t (M,) s, gyro (M, 3) rad/s, accel (M, 3) m/s^2)``.

    Raises:
        SequenceFormatError: bad columns/values, timestamps not strictly increasing, or
            a median sample rate below MIN_IMU_RATE_HZ.
    """
    path = Path(path)
    rows, lines = _read_numeric_table(path, 7, "t gx gy gz ax ay az")
    _check_increasing(path, rows[:, 0], lines)
    if len(rows) > 1:
        rate = 1.0 / float(np.median(np.diff(rows[:, 0])))
        if rate < MIN_IMU_RATE_HZ * (1 - 1e-6):
            raise SequenceFormatError(path, f"IMU rate {rate:.1f} Hz is below the required {MIN_IMU_RATE_HZ:.0f} Hz")
    return rows[:, 0].copy(), rows[:, 1:4].copy(), rows[:, 4:7].copy()


def write_tum_trajectory(path, t, T_w_c) -> None:
    """Write ``t: (N,)`` seconds and ``T_w_c: (N, 4, 4)`` camera-to-world poses (metres) in TUM format."""
    t = check_array("t", t, (None,), finite=True)
    T_w_c = check_array("T_w_c", T_w_c, (len(t), 4, 4), finite=True)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw (camera-to-world, metres)\n")
        for ti, T in zip(t, T_w_c):
            v = transform_to_tum(T)
            fh.write(f"{ti:.6f} " + " ".join(f"{x:.9f}" for x in v) + "\n")


def write_imu_txt(path, t, gyro, accel) -> None:
    """Write ``t: (M,)`` s, ``gyro: (M, 3)`` rad/s, ``accel: (M, 3)`` m/s^2 as imu.txt."""
    t = check_array("t", t, (None,), finite=True)
    gyro = check_array("gyro", gyro, (len(t), 3), finite=True)
    accel = check_array("accel", accel, (len(t), 3), finite=True)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp gx gy gz ax ay az (s, rad/s, m/s^2; IMU frame)\n")
        for ti, g, a in zip(t, gyro, accel):
            fh.write(f"{ti:.6f} {g[0]:.9f} {g[1]:.9f} {g[2]:.9f} {a[0]:.9f} {a[1]:.9f} {a[2]:.9f}\n")


# --------------------------------------------------------------------------- pixel readers
def read_rgb_image(path, camera: Camera | None = None) -> np.ndarray:
    """Read an image file as ``(H, W, 3)`` uint8 RGB (grey images are expanded to 3 channels).

    Raises:
        SequenceFormatError: missing/undecodable file, or its size differs from ``camera``'s.
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "image file not found")
    if path.suffix.lower() in (".jpg", ".jpeg") and not _has_jpeg_end(path):
        # checked here: libjpeg would print its own warning and decode a grey-filled image
        raise SequenceFormatError(path, "truncated JPEG (no end-of-image marker)")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR_RGB)
    if image is None:
        raise SequenceFormatError(path, "cannot decode image")
    if camera is not None and image.shape[:2] != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"image is {image.shape[1]}x{image.shape[0]} but the camera is {camera.width}x{camera.height}")
    return image


def _has_jpeg_end(path: Path) -> bool:
    """True when the JPEG file ends with the EOI marker FF D9 (trailing zero padding allowed)."""
    with open(path, "rb") as fh:
        fh.seek(max(0, path.stat().st_size - 64))
        tail = np.frombuffer(fh.read(), dtype=np.uint8)
    nz = np.flatnonzero(tail)
    return len(nz) >= 2 and tail[nz[-1]] == 0xD9 and tail[nz[-1] - 1] == 0xFF


def _load_depth(path: Path, camera: Camera, scale: float) -> np.ndarray:
    depth = read_depth_png(path, scale)
    if depth.shape != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"depth is {depth.shape[1]}x{depth.shape[0]} but the camera is {camera.width}x{camera.height}")
    return depth


def _load_disparity_npy(path: Path, camera: Camera) -> np.ndarray:
    if not path.is_file():
        raise SequenceFormatError(path, "disparity file not found")
    try:
        d = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise SequenceFormatError(path, f"cannot read disparity .npy: {exc}") from None
    if d.shape != (camera.height, camera.width):
        raise SequenceFormatError(path, f"disparity shape {d.shape} != camera (H, W) = {(camera.height, camera.width)}")
    if d.dtype.kind != "f":
        raise SequenceFormatError(path, f"disparity must be a float array, got {d.dtype}")
    return d.astype(np.float32, copy=False)


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


def _relative_file(root: Path, value, path: Path, where: str) -> Path:
    if not isinstance(value, str) or not value or Path(value).is_absolute():
        raise SequenceFormatError(path, f"{where} must be a relative path string, got {value!r}")
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
    dist = block.get("dist", [])
    if not isinstance(dist, list) or len(dist) not in (0, 4, 5):
        raise SequenceFormatError(path, f"camera.dist must be a list of 0, 4 (k1 k2 p1 p2) or 5 (+k3) numbers, got {dist!r}")
    dist = tuple(_number(d, path, "camera.dist[]") for d in dist)
    try:
        return Camera(vals["width"], vals["height"], vals["fx"], vals["fy"], vals["cx"], vals["cy"], dist)
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


@dataclass(frozen=True)
class DisparitySource:
    """Where a native sequence's disparity comes from.

    ``kind`` is "files" (``folder`` of ``<stem>.npy``) or "simulated" (SIMULATED from the GT
    depth at load time with ``seed`` and ``model``, see :mod:`vio_depth.simulate.disparity`).
    """

    kind: str
    folder: str | None = None
    seed: int | None = None
    model: object | None = None  # vio_depth.simulate.disparity.DisparitySimulation

    def to_json(self) -> dict:
        if self.kind == "files":
            return {"kind": "files", "folder": self.folder}
        return {"kind": "simulated", "seed": self.seed, "model": self.model.to_json()}


def files_disparity(folder: str = "disparity") -> DisparitySource:
    """Disparity stored as ``<folder>/<stem>.npy`` files."""
    return DisparitySource("files", folder=folder)


def simulated_disparity(seed: int, model=None) -> DisparitySource:
    """SIMULATED disparity (seed + frame index, :class:`DisparitySimulation` ``model``)."""
    from ..simulate.disparity import disparity_preset

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"simulated disparity seed must be a non-negative integer, got {seed!r}")
    return DisparitySource("simulated", seed=int(seed), model=disparity_preset("default") if model is None else model)


def _parse_disparity(block, path: Path) -> DisparitySource:
    if not isinstance(block, dict):
        raise SequenceFormatError(path, "disparity must be a JSON object")
    kind = _require(block, "kind", path, "disparity.")
    if kind == "files":
        _check_keys(block, {"kind", "folder"}, path, "disparity.")
        folder = _require(block, "folder", path, "disparity.")
        _relative_file(path.parent, folder, path, "disparity.folder")
        return DisparitySource("files", folder=folder)
    if kind == "simulated":
        from ..simulate.disparity import DisparitySimulation

        _check_keys(block, {"kind", "seed", "model"}, path, "disparity.")
        seed = _require(block, "seed", path, "disparity.")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise SequenceFormatError(path, f"disparity.seed must be a non-negative integer, got {seed!r}")
        model = _require(block, "model", path, "disparity.")
        if not isinstance(model, dict):
            raise SequenceFormatError(path, "disparity.model must be a JSON object")
        try:
            return DisparitySource("simulated", seed=seed, model=DisparitySimulation.from_json(model))
        except (InputError, TypeError) as exc:
            raise SequenceFormatError(path, f"disparity.model: {exc}") from None
    raise SequenceFormatError(path, f"disparity.kind must be 'files' or 'simulated', got {kind!r}")


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise SequenceFormatError(path, "sequence.json not found")
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except json.JSONDecodeError as exc:
        raise SequenceFormatError(path, f"invalid JSON: {exc.msg} (column {exc.colno})", exc.lineno) from None
    except UnicodeDecodeError as exc:
        raise SequenceFormatError(path, f"not UTF-8 text: {exc}") from None
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
        T_w_c: (N, 4, 4) camera-to-world pose of each frame, metres.
        image_paths: absolute image path of each frame.
        disparity_source: a :class:`DisparitySource` or None.
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
        poses_path = _relative_file(root, _require(meta, "poses", json_path, ""), json_path, "poses")
        t_frames, image_names, frame_lines = read_frames_txt(frames_path)
        self.timestamps = t_frames
        self.image_paths = []
        stems = {}
        for name_i, line in zip(image_names, frame_lines):
            p = _relative_file(root, name_i, frames_path, "image path")
            if not p.is_file():
                raise SequenceFormatError(frames_path, f"image file {name_i!r} not found", int(line))
            stem = Path(name_i).stem
            if stem in stems:
                raise SequenceFormatError(frames_path, f"image stem {stem!r} repeats line {stems[stem]}", int(line))
            stems[stem] = int(line)
            self.image_paths.append(p)
        self.stems = list(stems)

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

        self.disparity_source = None
        if meta.get("disparity") is not None:
            self.disparity_source = _parse_disparity(meta["disparity"], json_path)
            if self.disparity_source.kind == "simulated" and self._depth_folder is None:
                raise SequenceFormatError(json_path, "simulated disparity needs a depth block (it is computed from GT depth)")
        super().__init__(root, name, camera, imu)

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
        t, gyro, accel = read_imu_txt(imu_path)
        return ImuData(t, gyro, accel, T_c_i, gravity_w=gravity, **noise)

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def has_gt_depth(self) -> bool:
        return self._depth_folder is not None

    @property
    def has_disparity(self) -> bool:
        return self.disparity_source is not None

    @property
    def disparity_is_simulated(self) -> bool:
        return self.disparity_source is not None and self.disparity_source.kind == "simulated"

    def frame(self, index: int) -> Frame:
        """Frame ``index`` with lazy loaders (reads no pixels)."""
        if not 0 <= index < len(self):
            raise IndexError(index)
        camera = self.camera
        stem = self.stems[index]
        image_path = self.image_paths[index]
        load_depth = load_disparity = None
        if self._depth_folder is not None:
            depth_path = self._depth_folder / f"{stem}.png"
            scale = self._depth_scale

            def load_depth():
                return _load_depth(depth_path, camera, scale)

        src = self.disparity_source
        if src is not None and src.kind == "files":
            disparity_path = self.root / src.folder / f"{stem}.npy"

            def load_disparity():
                return _load_disparity_npy(disparity_path, camera)

        elif src is not None:
            seed, model, gt = src.seed, src.model, load_depth

            def load_disparity():
                from ..simulate.disparity import simulate_disparity

                return simulate_disparity(gt(), seed, index, model).disparity

        return Frame(
            index=index,
            timestamp=float(self.timestamps[index]),
            stem=stem,
            camera=camera,
            T_w_c=self.T_w_c[index].copy(),
            load_image=lambda: read_rgb_image(image_path, camera),
            load_gt_depth=load_depth,
            load_disparity=load_disparity,
            disparity_is_simulated=self.disparity_is_simulated,
        )


def detect_native(path) -> bool:
    """True when ``path`` is a folder holding a ``sequence.json``."""
    path = Path(path)
    return path.is_dir() and (path / "sequence.json").is_file()


def open_native(path) -> NativeSequence:
    return NativeSequence(path)


register_format(SequenceFormat(
    "native", detect_native, open_native,
    "vio-depth native folder with sequence.json (docs/sequence_format.md)",
))


# --------------------------------------------------------------------------- writing
# json.dumps(indent=2) puts every list item on its own line; raw newlines never occur inside
# JSON strings, so requiring them keeps string values untouched
_NUMBER_LIST = re.compile(r"\[\n\s*((?:-?[0-9.eE+-]+,\n\s*)*-?[0-9.eE+-]+)\n\s*\]")


def _dump_json(data: dict) -> str:
    """Indented JSON with innermost lists of numbers on one line (matrix rows stay readable)."""
    text = json.dumps(data, indent=2)
    return _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)

class NativeSequenceWriter:
    """Stream frames into a native sequence folder; :meth:`close` writes the text files.

    Images are written as they are added (nothing is kept in memory but timestamps and
    poses). Usage::

        with NativeSequenceWriter(root, "demo", camera) as w:
            w.set_imu(imu)                                   # optional
            w.set_disparity(simulated_disparity(seed=1))     # optional
            for t, image, T_w_c, depth in frames:
                w.add_frame(t, image, T_w_c, depth=depth)
    """

    def __init__(self, root, name: str, camera: Camera, *, image_ext: str = ".jpg", jpeg_quality: int = 90,
                 metadata: dict | None = None, overwrite: bool = False):
        self.root = Path(root)
        if (self.root / "sequence.json").exists() and not overwrite:
            raise InputError(f"{self.root}: already holds a sequence (pass overwrite=True to replace it)")
        if image_ext not in (".jpg", ".png"):
            raise InputError(f"image_ext must be '.jpg' or '.png', got {image_ext!r}")
        self.name = name
        self.camera = camera
        self.image_ext = image_ext
        self.jpeg_quality = int(jpeg_quality)
        self.metadata = dict(metadata or {})
        self._t: list[float] = []
        self._T: list[np.ndarray] = []
        self._stems: list[str] = []
        self._has_depth: bool | None = None
        self._imu: ImuData | None = None
        self._imu_simulation: dict | None = None
        self._disparity: DisparitySource | None = None
        (self.root / "images").mkdir(parents=True, exist_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()

    def set_imu(self, imu: ImuData, simulation: dict | None = None) -> None:
        """IMU samples to write to imu.txt (``simulation``: optional free-form JSON notes)."""
        self._imu = imu
        self._imu_simulation = simulation

    def set_disparity(self, source: DisparitySource) -> None:
        """Declare the disparity source; "files" disparities are then passed to :meth:`add_frame`."""
        self._disparity = source

    def add_frame(self, timestamp: float, image, T_w_c, *, depth=None, disparity=None, stem: str | None = None) -> str:
        """Write one frame.

        Args:
            timestamp: seconds, greater than the previous frame's.
            image: (H, W, 3) uint8 RGB (or (H, W) grey) of the camera's size.
            T_w_c: (4, 4) camera-to-world pose, metres.
            depth: optional (H, W) metres GT depth (NaN / <= 0 = invalid); all frames or none.
            disparity: (H, W) float disparity, required iff the disparity source is "files".
            stem: file stem (default: 6-digit frame number).

        Returns:
            the stem used.
        """
        image = np.asarray(image)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        image = check_image("image", image, channels=3)
        if image.dtype != np.uint8:
            raise InputError(f"image: expected uint8, got {image.dtype}")
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(f"image: size {image.shape[1]}x{image.shape[0]} differs from the camera's "
                             f"{self.camera.width}x{self.camera.height}")
        T_w_c = check_transform("T_w_c", T_w_c)
        if self._t and not timestamp > self._t[-1]:
            raise InputError(f"timestamps must increase: {timestamp} after {self._t[-1]}")
        stem = f"{len(self._t):06d}" if stem is None else str(stem)
        if stem in self._stems or not stem or any(c.isspace() for c in stem) or "/" in stem:
            raise InputError(f"stem {stem!r} is empty, repeated or contains spaces / slashes")
        if self._has_depth is None:
            self._has_depth = depth is not None
        elif self._has_depth != (depth is not None):
            raise InputError("give a depth map for every frame or for none")
        if (self._disparity is not None and self._disparity.kind == "files") != (disparity is not None):
            raise InputError("pass disparity to add_frame exactly when the disparity source is 'files'")

        image_path = self.root / "images" / f"{stem}{self.image_ext}"
        params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality] if self.image_ext == ".jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 9]
        if not cv2.imwrite(str(image_path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), params):
            raise InputError(f"{image_path}: cannot write image")
        if depth is not None:
            depth = check_array("depth", depth, (self.camera.height, self.camera.width))
            (self.root / "depth").mkdir(exist_ok=True)
            write_depth_png(self.root / "depth" / f"{stem}.png", depth)
        if disparity is not None:
            disparity = check_array("disparity", disparity, (self.camera.height, self.camera.width))
            folder = self.root / self._disparity.folder
            folder.mkdir(parents=True, exist_ok=True)
            np.save(folder / f"{stem}.npy", disparity.astype(np.float32))
        self._t.append(float(timestamp))
        self._T.append(T_w_c.copy())
        self._stems.append(stem)
        return stem

    def close(self) -> Path:
        """Write frames.txt, poses.txt, imu.txt and sequence.json; returns the folder."""
        if not self._t:
            raise InputError("no frames were added")
        if self._disparity is not None and self._disparity.kind == "simulated" and not self._has_depth:
            raise InputError("simulated disparity needs GT depth for every frame")
        with open(self.root / "frames.txt", "w", encoding="utf-8") as fh:
            fh.write("# timestamp image_path\n")
            for t, stem in zip(self._t, self._stems):
                fh.write(f"{t:.6f} images/{stem}{self.image_ext}\n")
        write_tum_trajectory(self.root / "poses.txt", np.asarray(self._t), np.stack(self._T))
        c = self.camera
        meta = {
            "format": FORMAT_TAG,
            "version": FORMAT_VERSION,
            "name": self.name,
            "camera": {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                       "dist": list(c.dist)},
            "frames": "frames.txt",
            "poses": "poses.txt",
        }
        if self._has_depth:
            meta["depth"] = {"folder": "depth", "scale": DEPTH_PNG_SCALE}
        if self._imu is not None:
            imu = self._imu
            write_imu_txt(self.root / "imu.txt", imu.t, imu.gyro, imu.accel)
            rate = 1.0 / float(np.median(np.diff(imu.t))) if len(imu.t) > 1 else 0.0
            meta["imu"] = {
                "file": "imu.txt",
                "T_c_i": np.asarray(imu.T_c_i, dtype=float).tolist(),
                "rate_hz": round(rate, 6),
                "gyro_noise_density": imu.gyro_noise,
                "accel_noise_density": imu.accel_noise,
                "gyro_bias_random_walk": imu.gyro_bias_walk,
                "accel_bias_random_walk": imu.accel_bias_walk,
                "gravity_w": [float(g) for g in imu.gravity_w],
            }
            if self._imu_simulation is not None:
                meta["imu"]["simulation"] = self._imu_simulation
        if self._disparity is not None:
            meta["disparity"] = self._disparity.to_json()
        if self.metadata:
            meta["metadata"] = self.metadata
        with open(self.root / "sequence.json", "w", encoding="utf-8") as fh:
            fh.write(_dump_json(meta) + "\n")
        return self.root


def write_native_sequence(root, name: str, camera: Camera, timestamps: Iterable[float], images: Iterable,
                          T_w_c: Iterable, *, depths: Iterable | None = None, imu: ImuData | None = None,
                          disparity: DisparitySource | None = None, disparities: Iterable | None = None,
                          stems: Iterable[str] | None = None, image_ext: str = ".jpg", jpeg_quality: int = 90,
                          metadata: dict | None = None, overwrite: bool = False) -> Path:
    """Write a whole native sequence in one call (iterables are consumed lazily, in step).

    Args:
        timestamps: N seconds. images: N (H, W, 3) uint8 RGB. T_w_c: N (4, 4) camera-to-world.
        depths: optional N (H, W) metres GT depth maps.
        imu: optional IMU samples. disparity: optional :class:`DisparitySource`;
        disparities: the N (H, W) arrays when ``disparity`` is :func:`files_disparity`.
        stems: optional N file stems (default 000000, 000001, ...).

    Returns:
        the sequence folder.
    """
    if disparities is not None and disparity is None:
        disparity = files_disparity()
    w = NativeSequenceWriter(root, name, camera, image_ext=image_ext, jpeg_quality=jpeg_quality,
                             metadata=metadata, overwrite=overwrite)
    if imu is not None:
        w.set_imu(imu)
    if disparity is not None:
        w.set_disparity(disparity)
    timestamps = list(timestamps)
    n = len(timestamps)
    it_img, it_T = iter(images), iter(T_w_c)
    it_depth = iter(depths) if depths is not None else None
    it_disp = iter(disparities) if disparities is not None else None
    it_stem = iter(stems) if stems is not None else None
    for i in range(n):
        try:
            image, T = next(it_img), next(it_T)
            depth = next(it_depth) if it_depth is not None else None
            disp = next(it_disp) if it_disp is not None else None
            stem = next(it_stem) if it_stem is not None else None
        except StopIteration:
            raise InputError(f"fewer images/poses/depths/disparities/stems than the {n} timestamps") from None
        w.add_frame(timestamps[i], image, T, depth=depth, disparity=disp, stem=stem)
    return w.close()


__all__ = [
    "FORMAT_TAG", "FORMAT_VERSION", "POSE_TIME_TOLERANCE_S", "NativeSequence", "NativeSequenceWriter",
    "DisparitySource", "files_disparity", "simulated_disparity", "write_native_sequence",
    "read_frames_txt", "read_tum_trajectory", "read_imu_txt", "write_tum_trajectory", "write_imu_txt",
    "read_rgb_image", "detect_native", "open_native",
]
