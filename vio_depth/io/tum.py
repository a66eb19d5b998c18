"""TUM RGB-D benchmark folders (``rgbd_dataset_freiburgX_*``).

Reads ``rgb.txt`` (``timestamp rgb/<file>.png``), ``depth.txt`` (16-bit PNG, metres x
5000, 0 = invalid; registered to the colour camera by the Kinect driver),
``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``: colour optical centre to world,
metres) and ``accelerometer.txt`` (``timestamp ax ay az`` m/s^2).

Association: every colour image takes the depth image with the nearest timestamp and
the pose interpolated between the two ground-truth samples around it; both must be
within ``max_time_difference`` (default 0.02 s). Colour images without a partner are
left out (the count is kept in :attr:`TumRgbdSequence.dropped`); when *no* image can be
associated with a file, that file is named in a :class:`SequenceFormatError`.

Intrinsics: ``camera.txt`` in the folder when present (one line ``fx fy cx cy [k1 k2 p1
p2 [k3]]``, pixels, OpenCV radial-tangential distortion), else the published Freiburg
1/2/3 calibration chosen by ``freiburg1``/``freiburg2``/``freiburg3`` in the folder name
(:data:`TUM_CAMERAS`), else an error asking for ``camera.txt``.

IMU: the Kinect has an accelerometer but no gyroscope, so the sequence has no
:class:`~vio_depth.types.ImuData` and ``--poses imu`` is not possible; the accelerometer
samples are kept in :attr:`TumRgbdSequence.accelerometer` for reference.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import InputError, SequenceFormatError
from ..types import Frame
from .base import Sequence, SequenceFormat, register_format
from .depth_png import read_depth_png
from .native import read_rgb_image

#: depth PNG units per metre
TUM_DEPTH_SCALE = 5000.0

#: Published colour-camera calibrations of the TUM RGB-D benchmark (640 x 480), by name.
#: Freiburg 3 images are already undistorted by the dataset (distortion 0).
TUM_CAMERAS: dict[str, Camera] = {
    "freiburg1": Camera(640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": Camera(640, 480, 520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": Camera(640, 480, 535.4, 539.2, 320.1, 247.6),
}
_FREIBURG_RE = re.compile(r"freiburg([0-9]+)")


@dataclass(frozen=True)
class TumSettings:
    """Options of the TUM RGB-D loader.

    Attributes:
        max_time_difference: seconds; largest timestamp gap accepted when associating
            a colour image with a depth image or a ground-truth pose (TUM's own
            ``associate.py`` uses 0.02 s).
    """

    max_time_difference: float = 0.02


def read_tum_list(path, n_values: int, *, numeric: bool) -> tuple[np.ndarray, list]:
    """Read a TUM text list: ``timestamp value...`` per line, ``#`` comments.

    Args:
        path: the file.
        n_values: number of values after the timestamp.
        numeric: parse the values as floats (else keep them as strings).

    Returns:
        ``(t (N,) seconds, rows)`` where rows is an (N, n_values) float array when
        ``numeric`` else a list of lists of strings.

    Raises:
        SequenceFormatError: naming file and line, for a short or non-numeric line or
            decreasing timestamps.
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "file not found")
    times, rows = [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) < 1 + n_values:
            raise SequenceFormatError(
                path, f"expected a timestamp and {n_values} values, got {len(parts)} fields", lineno)
        try:
            t = float(parts[0])
            vals = [float(p) for p in parts[1:1 + n_values]] if numeric else parts[1:1 + n_values]
        except ValueError:
            raise SequenceFormatError(path, f"non-numeric value in {s[:50]!r}", lineno) from None
        if times and t < times[-1]:
            raise SequenceFormatError(path, f"timestamp {t} is earlier than the previous line's", lineno)
        times.append(t)
        rows.append(vals)
    if not times:
        raise SequenceFormatError(path, "no entries")
    t = np.asarray(times, dtype=np.float64)
    return t, (np.asarray(rows, dtype=np.float64).reshape(len(t), n_values) if numeric else rows)


def associate_nearest(t_query, t_ref, max_difference: float) -> np.ndarray:
    """Index of the nearest reference timestamp for each query, -1 when none is close enough.

    Args:
        t_query: (N,) seconds.
        t_ref: (M,) seconds, non-decreasing.
        max_difference: seconds.

    Returns:
        (N,) int64 indices into ``t_ref`` (-1 = farther than ``max_difference``).
    """
    q = check_array("t_query", t_query, (None,), finite=True)
    r = check_array("t_ref", t_ref, (None,), finite=True)
    if len(r) == 0:
        return np.full(len(q), -1, np.int64)
    hi = np.clip(np.searchsorted(r, q), 1, max(len(r) - 1, 1))
    lo = hi - 1
    if len(r) == 1:
        best = np.zeros(len(q), np.int64)
    else:
        best = np.where(np.abs(r[lo] - q) <= np.abs(r[hi] - q), lo, hi)
    return np.where(np.abs(r[best] - q) <= max_difference, best, -1).astype(np.int64)


def interpolate_poses(t_query, t_ref, T_ref, max_difference: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``t_query`` interpolated between the reference samples around each time.

    Translation is interpolated linearly and rotation along the geodesic. A query needs
    a reference sample within ``max_difference``; when the query is not bracketed by
    two samples (or the bracketing gap exceeds ``2 * max_difference``) the nearest
    sample's pose is used.

    Args:
        t_query: (N,) seconds.
        t_ref: (M,) seconds, non-decreasing.
        T_ref: (M, 4, 4) poses at ``t_ref``.
        max_difference: seconds.

    Returns:
        ``(T (N, 4, 4), ok (N,) bool)``; rows with ``ok`` False are identity.
    """
    q = check_array("t_query", t_query, (None,), finite=True)
    r = check_array("t_ref", t_ref, (None,), finite=True)
    T = check_array("T_ref", T_ref, (len(r), 4, 4), finite=True)
    nearest = associate_nearest(q, r, max_difference)
    ok = nearest >= 0
    out = np.tile(np.eye(4), (len(q), 1, 1))
    if not ok.any():
        return out, ok
    out[ok] = T[nearest[ok]]
    if len(r) >= 2:
        j = np.clip(np.searchsorted(r, q, side="right") - 1, 0, len(r) - 2)
        gap = r[j + 1] - r[j]
        brk = ok & (r[j] <= q) & (q <= r[j + 1]) & (gap > 0) & (gap <= 2 * max_difference)
        if brk.any():
            jb = j[brk]
            a = (q[brk] - r[jb]) / gap[brk]
            R0 = Rotation.from_matrix(T[jb, :3, :3])
            R1 = Rotation.from_matrix(T[jb + 1, :3, :3])
            step = (R0.inv() * R1).as_rotvec()
            out[brk, :3, :3] = (R0 * Rotation.from_rotvec(step * a[:, None])).as_matrix()
            out[brk, :3, 3] = (1 - a)[:, None] * T[jb, :3, 3] + a[:, None] * T[jb + 1, :3, 3]
    return out, ok


def parse_camera_txt(path) -> tuple[float, ...]:
    """``camera.txt``: first non-comment line ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` -> floats."""
    path = Path(path)
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            values = tuple(float(v) for v in s.split())
        except ValueError:
            raise SequenceFormatError(path, f"non-numeric value in {s[:50]!r}", lineno) from None
        if len(values) not in (4, 8, 9):
            raise SequenceFormatError(
                path, f"expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]', got {len(values)} values", lineno)
        return values
    raise SequenceFormatError(path, "no camera line")


def tum_camera(folder, width: int, height: int) -> Camera:
    """Intrinsics of the TUM folder: ``camera.txt`` if present, else :data:`TUM_CAMERAS` by folder name.

    Raises:
        SequenceFormatError: neither is available (names the folder) or camera.txt is malformed.
    """
    folder = Path(folder)
    cam_file = folder / "camera.txt"
    if cam_file.is_file():
        v = parse_camera_txt(cam_file)
        try:
            return Camera(width, height, v[0], v[1], v[2], v[3], v[4:])
        except InputError as e:
            raise SequenceFormatError(cam_file, str(e)) from None
    m = _FREIBURG_RE.search(folder.resolve().name)
    if m and f"freiburg{m.group(1)}" in TUM_CAMERAS:
        cam = TUM_CAMERAS[f"freiburg{m.group(1)}"]
        if (cam.width, cam.height) != (width, height):
            cam = cam.scaled(width / cam.width, height / cam.height)
        return cam
    raise SequenceFormatError(folder, "cannot tell the camera: the folder name names no known Freiburg camera "
                                      f"({', '.join(sorted(TUM_CAMERAS))}) and there is no camera.txt "
                                      "('fx fy cx cy [k1 k2 p1 p2 [k3]]')")


class TumRgbdSequence(Sequence):
    """A TUM RGB-D folder: colour images with associated depth and ground-truth poses.

    Attributes:
        dropped: number of colour images left out because no depth image or pose was
            within ``settings.max_time_difference``.
        accelerometer: ``(t (M,) s, accel (M, 3) m/s^2)`` Kinect accelerometer samples,
            or None. Not usable for ``--poses imu`` (no gyroscope).
    """

    format_name = "tum_rgbd"
    imu_missing_reason = "TUM RGB-D has an accelerometer but no gyroscope, so poses cannot be preintegrated"

    def __init__(self, path, settings: TumSettings = TumSettings()):
        folder = Path(path)
        rgb_file = folder / "rgb.txt"
        if not rgb_file.is_file():
            raise InputError(f"{folder}: no rgb.txt (not a TUM RGB-D folder)")
        self.settings = settings
        tol = settings.max_time_difference
        t_rgb, rgb_rows = read_tum_list(rgb_file, 1, numeric=False)
        keep = np.ones(len(t_rgb), bool)

        depth_file = folder / "depth.txt"
        depth_paths = None
        if depth_file.is_file():
            t_depth, depth_rows = read_tum_list(depth_file, 1, numeric=False)
            idx = associate_nearest(t_rgb, t_depth, tol)
            if not (idx >= 0).any():
                raise SequenceFormatError(depth_file, (
                    f"no depth timestamp within {tol} s of any rgb.txt timestamp "
                    f"(rgb {t_rgb[0]:.3f}..{t_rgb[-1]:.3f}, depth {t_depth[0]:.3f}..{t_depth[-1]:.3f})"))
            keep &= idx >= 0
            depth_paths = [folder / depth_rows[i][0] if i >= 0 else None for i in idx]

        gt_file = folder / "groundtruth.txt"
        poses = None
        if gt_file.is_file():
            t_gt, gt_rows = read_tum_list(gt_file, 7, numeric=True)
            q_norm = np.linalg.norm(gt_rows[:, 3:], axis=1)
            if np.any(np.abs(q_norm - 1) > 0.01):
                bad = int(np.argmax(np.abs(q_norm - 1) > 0.01))
                raise SequenceFormatError(gt_file, f"quaternion of entry {bad + 1} has norm {q_norm[bad]:.3f}, not 1")
            T_gt = np.tile(np.eye(4), (len(t_gt), 1, 1))
            T_gt[:, :3, :3] = Rotation.from_quat(gt_rows[:, 3:] / q_norm[:, None]).as_matrix()
            T_gt[:, :3, 3] = gt_rows[:, :3]
            poses, ok = interpolate_poses(t_rgb, t_gt, T_gt, tol)
            if not ok.any():
                raise SequenceFormatError(gt_file, (
                    f"no pose timestamp within {tol} s of any rgb.txt timestamp "
                    f"(rgb {t_rgb[0]:.3f}..{t_rgb[-1]:.3f}, groundtruth {t_gt[0]:.3f}..{t_gt[-1]:.3f})"))
            keep &= ok
        if not keep.any():
            raise SequenceFormatError(rgb_file, "no colour image has both a depth image and a pose within "
                                                f"{tol} s (depth.txt and groundtruth.txt cover different times)")

        sel = np.nonzero(keep)[0]
        self.dropped = int(len(t_rgb) - len(sel))
        self._times = t_rgb[sel]
        self._rgb = [folder / rgb_rows[i][0] for i in sel]
        self._depth = None if depth_paths is None else [depth_paths[i] for i in sel]
        self._poses = None if poses is None else poses[sel]

        acc_file = folder / "accelerometer.txt"
        self.accelerometer = None
        if acc_file.is_file():
            t_acc, acc = read_tum_list(acc_file, 3, numeric=True)
            self.accelerometer = (t_acc, acc)

        first = read_rgb_image(self._rgb[0])
        camera = tum_camera(folder, first.shape[1], first.shape[0])
        super().__init__(folder, folder.name, camera, imu=None)

    def __len__(self) -> int:
        return len(self._rgb)

    @property
    def has_gt_depth(self) -> bool:
        return self._depth is not None

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) colour-image timestamps, seconds."""
        return self._times.copy()

    def frame(self, index: int) -> Frame:
        rgb = self._rgb[index]
        return Frame(
            index=index,
            timestamp=float(self._times[index]),
            stem=rgb.stem,
            camera=self.camera,
            T_w_c=None if self._poses is None else self._poses[index].copy(),
            load_image=partial(read_rgb_image, rgb, self.camera),
            load_gt_depth=None if self._depth is None else partial(read_depth_png, self._depth[index], TUM_DEPTH_SCALE),
        )


def _detect(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.txt").is_file() and (
        (path / "depth.txt").is_file() or (path / "groundtruth.txt").is_file())


register_format(SequenceFormat(
    "tum_rgbd", _detect, TumRgbdSequence,
    "TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt, accelerometer.txt)",
))
