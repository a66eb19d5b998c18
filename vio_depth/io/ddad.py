"""DDAD scenes in the published DGP layout (TRI-ML/DDAD, read as TRI-ML/dgp does).

One scene folder (``ddad_train_val/000150/``)::

    scene_<sha1>.json              the Scene: "data" (datums) and "samples"
    calibration/<sha1>.json        per calibration key: "names", "intrinsics", "extrinsics"
    rgb/CAMERA_01/<ts>.png         camera images (1936 x 1216 in DDAD)
    point_cloud/LIDAR/<ts>.npz     LiDAR points in the sensor frame, key "data"

What is read (field names as protobuf's JSON writes them, snake_case or lowerCamelCase):

* **frames**: the samples of the scene in order; each sample lists ``datum_keys``, and the
  datum (``data[*]``, matched by ``key``) whose ``id.name`` is the chosen camera
  (:class:`DdadSettings`, default ``CAMERA_01``, case-insensitive) is the frame:
  ``datum.image.filename`` the image, ``height``/``width`` its size, ``id.timestamp``
  (RFC 3339) its time, ``datum.image.pose`` the camera-to-world pose (``pose_WC``:
  ``translation`` x/y/z metres, ``rotation`` qw/qx/qy/qz) -- absent or zero: no pose.
* **intrinsics**: ``calibration/<sample.calibration_key>.json``, the entry of
  ``intrinsics`` at the camera's index in ``names``: ``fx fy cx cy`` (``k1 k2 p1 p2 k3``
  when present; ``skew`` and ``fisheye`` must be 0).
* **ground-truth depth**: the sample's LiDAR datum (default name ``LIDAR``), its
  ``point_cloud.filename`` (``.npz`` with ``data``: an (N, >=3) array whose X, Y, Z columns
  follow ``point_format``, or a structured array with fields X, Y, Z), in the LiDAR frame.
  Moved into the camera with the calibration **extrinsics** (each sensor's pose in the
  vehicle frame: ``T_c_l = T_v_c^-1 T_v_l``, the default) or, with
  ``project_with="poses"``, with the two datums' world poses (``T_c_l = pose_WC^-1
  pose_WS``: what DGP's ``generate_depth_map`` does, compensating the vehicle's motion
  between the LiDAR and camera timestamps). Projected with the camera model, the nearest
  point per pixel kept (DGP truncates pixel coordinates and keeps the last point written;
  here pixel centres are rounded and the nearest wins), 0 = no return.
* No IMU (DDAD has none): ``--poses imu`` is refused.

``open_sequence`` accepts the scene folder or its ``scene_*.json``; a folder of scene
folders (the dataset root with ``ddad.json``) is refused with the list of scenes
(:func:`find_ddad_scenes` and :func:`ddad_split_scenes` enumerate them for evaluations).
Malformed files raise :class:`~vio_core.errors.SequenceFormatError` naming the file (and
the line for JSON syntax errors).
"""

from __future__ import annotations

import calendar
import json
import re
import zipfile
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SequenceFormatError, SettingsError, UnknownNameError
from vio_core.geometry import invert_transform, make_transform
from vio_core.limits import read_json_file

from ..frame import Frame
from .base import Sequence, SequenceFormat
from .images import read_rgb_image
from .tables import MAX_POSITION_M, QUATERNION_NORM_TOLERANCE, inside_name

#: how the LiDAR points are moved into the camera (see the module docstring)
PROJECTIONS = ("extrinsics", "poses")
#: DGP split names and their enum values in ``scene_splits`` of a dataset JSON
DGP_SPLITS = {"train": 0, "val": 1, "test": 2, "train_overfit": 3}

#: DGP PointCloud.ChannelType numbers of the channels read (JSON may give names or numbers)
_CHANNELS = {0: "X", 1: "Y", 2: "Z", 3: "INTENSITY"}
_SCENE_GLOB = "scene_*.json"
_TIMESTAMP_RE = re.compile(
    r"^(\d{4})-(\d{2})-(\d{2})T(\d{2}):(\d{2}):(\d{2})(?:\.(\d+))?(Z|[+-]\d{2}:\d{2})$")


@dataclass(frozen=True)
class DdadSettings:
    """Options of the DDAD loader.

    Attributes:
        camera: datum name of the camera (``CAMERA_01`` = front; DDAD has 01, 05-09).
        lidar: datum name of the point cloud used as ground truth.
        project_with: one of :data:`PROJECTIONS`.
        min_depth: metres; LiDAR points nearer to the camera than this are dropped.
    """

    camera: str = "CAMERA_01"
    lidar: str = "LIDAR"
    project_with: str = "extrinsics"
    min_depth: float = 0.1

    def __post_init__(self):
        if self.project_with not in PROJECTIONS:
            raise UnknownNameError("DDAD projection", self.project_with, PROJECTIONS)
        if not self.min_depth >= 0:
            raise SettingsError(f"DDAD min_depth must be >= 0, got {self.min_depth}")


# --------------------------------------------------------------------------- JSON helpers
def read_json(path) -> object:
    """Parse a JSON file; :class:`SequenceFormatError` with the line of a syntax error."""
    path = Path(path)
    try:
        return read_json_file(path, what="a JSON file")
    except json.JSONDecodeError as exc:
        raise SequenceFormatError(path, f"invalid JSON: {exc.msg} (column {exc.colno})", line=exc.lineno) from None
    except (OSError, ValueError) as exc:  # unreadable, too large, nested too deeply, not UTF-8
        raise SequenceFormatError(path, f"cannot read JSON: {exc}") from None


def _get(obj, name: str, default=None):
    """Field ``name`` (snake_case) of a protobuf-JSON object, also under its lowerCamelCase name."""
    if not isinstance(obj, dict):
        return default
    if name in obj:
        return obj[name]
    parts = name.split("_")
    return obj.get(parts[0] + "".join(p.title() for p in parts[1:]), default)


def _require(obj, name: str, path: Path, where: str):
    value = _get(obj, name)
    if value is None:
        raise SequenceFormatError(path, f"{where}: missing {name!r}")
    return value


def _number(obj, name: str, path: Path, where: str, default: float = 0.0) -> float:
    value = _get(obj, name, default)
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise SequenceFormatError(path, f"{where}: {name!r} is not a number: {value!r}") from None
    if not np.isfinite(value):
        raise SequenceFormatError(path, f"{where}: {name!r} is not finite")
    return value


def parse_pose(obj, path, where: str) -> np.ndarray | None:
    """(4, 4) transform of a DGP ``Pose`` (``translation`` x/y/z, ``rotation`` qw/qx/qy/qz).

    Returns None when the pose is absent or its quaternion is all zero (proto3 omits
    default fields). Raises :class:`SequenceFormatError` for a non-unit quaternion.
    """
    path = Path(path)
    if obj is None or obj == {}:
        return None
    if not isinstance(obj, dict):
        raise SequenceFormatError(path, f"{where}: pose must be an object, got {type(obj).__name__}")
    t = _get(obj, "translation", {}) or {}
    r = _get(obj, "rotation", {}) or {}
    q = np.array([_number(r, k, path, f"{where}.rotation") for k in ("qx", "qy", "qz", "qw")])
    norm = float(np.linalg.norm(q))
    if norm == 0.0:
        return None
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise SequenceFormatError(path, f"{where}: rotation quaternion norm {norm:.4f} is not 1")
    xyz = [_number(t, k, path, f"{where}.translation") for k in ("x", "y", "z")]
    if not all(abs(v) <= MAX_POSITION_M for v in xyz):
        raise SequenceFormatError(path, f"{where}: translation {xyz} m is beyond the plausible {MAX_POSITION_M:.0e} m")
    return make_transform(Rotation.from_quat(q / norm).as_matrix(), xyz)


def parse_timestamp(text, path, where: str) -> float:
    """Seconds since the Unix epoch of an RFC 3339 timestamp (protobuf's JSON form)."""
    m = _TIMESTAMP_RE.match(str(text)) if isinstance(text, str) else None
    if m is None:
        raise SequenceFormatError(path, f"{where}: timestamp {text!r} is not RFC 3339 (YYYY-MM-DDTHH:MM:SS[.f]Z)")
    y, mo, d, h, mi, s = (int(g) for g in m.groups()[:6])
    frac = float("0." + m.group(7)) if m.group(7) else 0.0
    tz = m.group(8)
    offset = 0 if tz == "Z" else (1 if tz[0] == "+" else -1) * (int(tz[1:3]) * 3600 + int(tz[4:6]) * 60)
    try:
        seconds = calendar.timegm((y, mo, d, h, mi, s, 0, 0, 0))
    except (ValueError, OverflowError):
        raise SequenceFormatError(path, f"{where}: invalid timestamp {text!r}") from None
    return float(seconds - offset) + frac


# --------------------------------------------------------------------------- calibration
@dataclass(frozen=True)
class DdadSensor:
    """One sensor of a calibration file: its camera (None for a LiDAR) and ``T_v_s`` (4, 4) sensor-to-vehicle."""

    camera: Camera | None
    T_v_s: np.ndarray


def read_calibration(path, image_sizes: dict[str, tuple[int, int]]) -> dict[str, DdadSensor]:
    """Sensors of a DGP calibration JSON, by lower-case name.

    Args:
        path: ``calibration/<key>.json``.
        image_sizes: lower-case camera name -> (width, height) px (from the image datums).
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "calibration file not found")
    cal = read_json(path)
    names = _require(cal, "names", path, "calibration")
    intr = _require(cal, "intrinsics", path, "calibration")
    extr = _require(cal, "extrinsics", path, "calibration")
    if not (isinstance(names, list) and isinstance(intr, list) and isinstance(extr, list)):
        raise SequenceFormatError(path, "calibration: 'names', 'intrinsics' and 'extrinsics' must be lists")
    if not len(names) == len(intr) == len(extr):
        raise SequenceFormatError(path, f"calibration: {len(names)} names, {len(intr)} intrinsics and "
                                        f"{len(extr)} extrinsics (must be equal)")
    out = {}
    for name, k, e in zip(names, intr, extr):
        where = f"sensor {name!r}"
        T = parse_pose(e, path, f"{where} extrinsics")
        T = np.eye(4) if T is None else T
        fx, fy = _number(k, "fx", path, where), _number(k, "fy", path, where)
        camera = None
        if fx > 0 and fy > 0:  # DGP: intrinsics with fx = fy = 0 belong to a LiDAR
            if _number(k, "skew", path, where) != 0.0:
                raise SequenceFormatError(path, f"{where}: skewed intrinsics are not supported")
            if _number(k, "fisheye", path, where) != 0.0:
                raise SequenceFormatError(path, f"{where}: fisheye cameras are not supported")
            dist = tuple(_number(k, c, path, where) for c in ("k1", "k2", "p1", "p2", "k3"))
            size = image_sizes.get(str(name).lower())
            if size is not None:
                try:
                    camera = Camera(size[0], size[1], fx, fy, _number(k, "cx", path, where),
                                    _number(k, "cy", path, where), dist if any(dist) else ())
                except InputError as exc:
                    raise SequenceFormatError(path, f"{where}: {exc}") from None
        out[str(name).lower()] = DdadSensor(camera, T)
    return out


# --------------------------------------------------------------------------- LiDAR
def read_lidar_npz(path, point_format=None) -> np.ndarray:
    """(N, 3) float64 metres, the X, Y, Z columns of a DGP point-cloud ``.npz`` (key ``data``)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "data" not in z.files:
                raise SequenceFormatError(path, f"expected key 'data', found {z.files}")
            data = z["data"]
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise SequenceFormatError(path, f"cannot read point cloud: {exc}") from None
    if data.dtype.fields is not None:
        if not all(f in data.dtype.fields for f in "XYZ"):
            raise SequenceFormatError(path, f"structured point cloud needs fields X, Y, Z, has {list(data.dtype.fields)}")
        xyz = np.stack([data["X"], data["Y"], data["Z"]], axis=-1).reshape(-1, 3)
    else:
        cols = [0, 1, 2]
        if point_format:
            fmt = [_CHANNELS.get(int(f), str(f)) if str(f).isdigit() else str(f).upper() for f in point_format]
            if not all(c in fmt for c in "XYZ"):
                raise SequenceFormatError(path, f"point_format {list(point_format)} has no X, Y and Z channels")
            cols = [fmt.index(c) for c in "XYZ"]
        if data.ndim != 2 or data.shape[1] <= max(cols):
            raise SequenceFormatError(path, f"point cloud must be (N, >= {max(cols) + 1}), got shape {data.shape}")
        xyz = data[:, cols]
    xyz = np.asarray(xyz, dtype=np.float64)
    return xyz[np.isfinite(xyz).all(axis=1)]


def project_points_to_depth(points_c, camera: Camera, min_depth: float = 0.1) -> np.ndarray:
    """Sparse depth image of points in the camera frame, nearest point per pixel.

    Args:
        points_c: (N, 3) metres, camera frame (z forward).
        camera: the camera (with distortion: points are projected to raw pixels).
        min_depth: metres; nearer points are dropped.

    Returns:
        (H, W) float32 metres, 0 = no point.
    """
    p = check_array("points_c", points_c, (None, 3))
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] > min_depth)]
    depth = np.zeros((camera.height, camera.width), np.float32)
    if len(p) == 0:
        return depth
    uv, z = camera.project(p)
    if camera.is_distorted:
        uv = camera.distort_points(uv)
    col = np.round(uv[:, 0]).astype(np.int64)
    row = np.round(uv[:, 1]).astype(np.int64)
    inside = (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    col, row, z = col[inside], row[inside], z[inside]
    order = np.argsort(-z, kind="stable")  # far first: nearer points overwrite them
    depth[row[order], col[order]] = z[order]
    return depth


def _load_depth(npz: Path, point_format, T_c_l: np.ndarray, camera: Camera, min_depth: float) -> np.ndarray:
    pts = read_lidar_npz(npz, point_format)
    return project_points_to_depth(pts @ T_c_l[:3, :3].T + T_c_l[:3, 3], camera, min_depth)


# --------------------------------------------------------------------------- scenes
def find_ddad_scenes(path) -> list[Path]:
    """Scene folders (holding a ``scene_*.json``) at or directly below ``path``, sorted."""
    path = Path(path)
    if path.is_file():
        return [path.parent] if path.match(_SCENE_GLOB) else []
    if not path.is_dir():
        return []
    if any(path.glob(_SCENE_GLOB)):
        return [path]
    return sorted(p for p in path.iterdir() if p.is_dir() and any(p.glob(_SCENE_GLOB)))


def ddad_split_scenes(dataset_json, split: str = "val") -> list[Path]:
    """Scene JSON paths of ``split`` in a DGP dataset JSON (``ddad.json``: ``scene_splits``)."""
    path = Path(dataset_json)
    if split not in DGP_SPLITS:
        raise UnknownNameError("DGP split", split, DGP_SPLITS)
    ds = read_json(path)
    splits = _require(ds, "scene_splits", path, "dataset")
    files = _get(splits.get(str(DGP_SPLITS[split]), {}), "filenames", [])
    if not files:
        raise SequenceFormatError(path, f"no scenes in split {split!r} (scene_splits key {DGP_SPLITS[split]})")
    return [path.parent / inside_name(f, path, "scene_splits") for f in files]



def _scene_json(path: Path) -> Path:
    if path.is_file():
        return path
    found = sorted(path.glob(_SCENE_GLOB))
    if len(found) == 1:
        return found[0]
    if len(found) > 1:
        raise InputError(f"{path}: several scene JSON files; open one of: " + ", ".join(p.name for p in found))
    scenes = find_ddad_scenes(path)
    if scenes:
        more = "" if len(scenes) <= 5 else f" (and {len(scenes) - 5} more)"
        raise InputError(f"{path}: a DDAD dataset with {len(scenes)} scenes; open one scene folder, e.g. "
                         + ", ".join(str(p) for p in scenes[:5]) + more)
    raise InputError(f"{path}: no scene_*.json (not a DDAD / DGP scene folder)")


@dataclass(frozen=True)
class _DdadFrame:
    stem: str
    image: Path
    timestamp: float
    T_w_c: np.ndarray | None
    calibration_key: str
    lidar: Path | None
    lidar_format: tuple
    T_w_l: np.ndarray | None


class DdadSequence(Sequence):
    """One DDAD (DGP) scene as a sequence of one camera's frames (see the module docstring).

    Args:
        path: the scene folder or its ``scene_*.json``.
        settings: :class:`DdadSettings`.

    Attributes:
        scene_json: the scene file read.
        sensors: lower-case sensor name -> :class:`DdadSensor` of the first calibration.
    """

    format_name = "ddad"
    pose_kind = "ins"

    def __init__(self, path, settings: DdadSettings = DdadSettings()):
        self.settings = settings
        self.scene_json = scene_json = _scene_json(Path(path))
        folder = scene_json.parent
        scene = read_json(scene_json)
        if not isinstance(scene, dict):
            raise SequenceFormatError(scene_json, "scene must be a JSON object")
        data = _require(scene, "data", scene_json, "scene")
        samples = _require(scene, "samples", scene_json, "scene")
        if not isinstance(data, list) or not isinstance(samples, list):
            raise SequenceFormatError(scene_json, "scene: 'data' and 'samples' must be lists")
        by_key = {}
        for i, datum in enumerate(data):
            key = _get(datum, "key")
            if not isinstance(key, str) or not key:
                raise SequenceFormatError(scene_json, f"data[{i}]: missing 'key'")
            by_key[key] = datum
        cam_name, lidar_name = settings.camera.lower(), settings.lidar.lower()
        frames, sizes, names = [], {}, set()
        for s_idx, sample in enumerate(samples):
            where = f"samples[{s_idx}]"
            keys = _require(sample, "datum_keys", scene_json, where)
            calib_key = _require(sample, "calibration_key", scene_json, where)
            cam = lidar = None
            for key in keys:
                if key not in by_key:
                    raise SequenceFormatError(scene_json, f"{where}: datum key {key!r} is not in 'data'")
                datum = by_key[key]
                name = str(_get(_get(datum, "id", {}), "name", "")).lower()
                names.add(name)
                if name == cam_name:
                    cam = datum
                elif name == lidar_name:
                    lidar = datum
            if cam is None:
                continue
            frames.append(self._frame(cam, lidar, calib_key, folder, scene_json, sizes))
        if not frames:
            raise InputError(f"{scene_json}: no sample has a datum named {settings.camera!r}; datums: "
                             + ", ".join(sorted(n.upper() for n in names if n)))
        self._frames = frames
        self._calibrations: dict[str, dict[str, DdadSensor]] = {}
        for key in dict.fromkeys(f.calibration_key for f in frames):
            self._calibrations[key] = read_calibration(folder / "calibration" / f"{key}.json", sizes)
        first = self._calibrations[frames[0].calibration_key]
        for key, cal in self._calibrations.items():
            cal_path = folder / "calibration" / f"{key}.json"
            if cam_name not in cal or cal[cam_name].camera is None:
                raise SequenceFormatError(cal_path, f"no camera intrinsics for {settings.camera!r}; sensors: "
                                                    + ", ".join(n.upper() for n in cal))
            if any(f.lidar is not None for f in frames) and lidar_name not in cal and settings.project_with == "extrinsics":
                raise SequenceFormatError(cal_path, f"no extrinsics for {settings.lidar!r}")
        self.sensors = first
        camera = first[cam_name].camera
        for key, cal in self._calibrations.items():
            if cal[cam_name].camera != camera:
                raise InputError(f"{scene_json}: the intrinsics of {settings.camera} change within the scene "
                                 f"(calibration {key}); not supported")
        if np.any(np.diff([f.timestamp for f in frames]) <= 0):
            raise SequenceFormatError(scene_json, f"{settings.camera} timestamps are not strictly increasing")
        super().__init__(folder, folder.name, camera, imu=None)

    def _frame(self, cam, lidar, calib_key, folder: Path, scene_json: Path, sizes) -> _DdadFrame:
        key = _get(cam, "key")
        where = f"datum {key!r}"
        image = _get(_get(cam, "datum", {}), "image")
        if not isinstance(image, dict):
            raise SequenceFormatError(scene_json, f"{where}: {self.settings.camera} datum has no 'image'")
        filename = inside_name(_require(image, "filename", scene_json, where), scene_json, where)
        w, h = int(_number(image, "width", scene_json, where)), int(_number(image, "height", scene_json, where))
        if w <= 0 or h <= 0:
            raise SequenceFormatError(scene_json, f"{where}: image size must be positive, got {w}x{h}")
        name = self.settings.camera.lower()
        if sizes.setdefault(name, (w, h)) != (w, h):
            raise SequenceFormatError(scene_json, f"{where}: image size {w}x{h} differs from earlier frames")
        stamp = parse_timestamp(_get(_get(cam, "id", {}), "timestamp"), scene_json, where)
        T_w_c = parse_pose(_get(image, "pose"), scene_json, f"{where} pose")
        lidar_path, fmt, T_w_l = None, (), None
        if lidar is not None:
            pc = _get(_get(lidar, "datum", {}), "point_cloud")
            lwhere = f"datum {_get(lidar, 'key')!r}"
            if not isinstance(pc, dict):
                raise SequenceFormatError(scene_json, f"{lwhere}: {self.settings.lidar} datum has no 'point_cloud'")
            lidar_path = folder / inside_name(_require(pc, "filename", scene_json, lwhere), scene_json, lwhere)
            fmt = tuple(_get(pc, "point_format", []) or [])
            T_w_l = parse_pose(_get(pc, "pose"), scene_json, f"{lwhere} pose")
        return _DdadFrame(Path(filename).stem, folder / filename, stamp, T_w_c, str(calib_key), lidar_path, fmt, T_w_l)

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def has_gt_depth(self) -> bool:
        return any(f.lidar is not None for f in self._frames)

    def T_c_l(self, index: int) -> np.ndarray | None:
        """(4, 4) LiDAR-to-camera transform of frame ``index`` (None when it cannot be formed)."""
        f = self._frames[index]
        if self.settings.project_with == "poses":
            if f.T_w_c is None or f.T_w_l is None:
                return None
            return invert_transform(f.T_w_c) @ f.T_w_l
        cal = self._calibrations[f.calibration_key]
        return invert_transform(cal[self.settings.camera.lower()].T_v_s) @ cal[self.settings.lidar.lower()].T_v_s

    def frame(self, index: int) -> Frame:
        f = self._frames[index]
        loader = None
        if f.lidar is not None:
            T = self.T_c_l(index)
            if T is None:
                raise SequenceFormatError(self.scene_json, f"frame {f.stem}: project_with='poses' needs the poses "
                                                           f"of {self.settings.camera} and {self.settings.lidar}")
            loader = partial(_load_depth, f.lidar, f.lidar_format, check_transform("T_c_l", T), self.camera,
                             self.settings.min_depth)
        return Frame(
            index=index,
            timestamp=f.timestamp,
            stem=f.stem,
            camera=self.camera,
            T_w_c=None if f.T_w_c is None else f.T_w_c.copy(),
            load_image=partial(read_rgb_image, f.image, self.camera),
            load_gt_depth=loader,
        )


def _detect(path: Path) -> bool:
    if path.is_file():
        return path.match(_SCENE_GLOB)
    return bool(find_ddad_scenes(path)) and not (path / "sequence.json").is_file()


FORMAT = SequenceFormat(
    "ddad", _detect, DdadSequence,
    "DDAD / DGP scene (scene_*.json, calibration/, rgb/<CAMERA>/, point_cloud/<LIDAR>/*.npz)",
)
