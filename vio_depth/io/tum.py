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
:class:`~vio_depth.frame.ImuData` and ``--poses imu`` is not possible; the accelerometer
samples are kept in :attr:`TumRgbdSequence.accelerometer` for reference.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError

from ..frame import Frame
from .base import Sequence, SequenceFormat
from .depth_png import read_depth_png
from .images import read_rgb_image
from .tables import (
    TextTable,
    associate_nearest,
    interpolate_poses,
    read_text_table,
    read_tum_trajectory,
    stays_inside,
)

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


def parse_camera_txt(path) -> tuple[float, ...]:
    """``camera.txt``: first non-comment line ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` -> floats."""
    table = read_text_table(path, "camera", layout="fx fy cx cy [k1 k2 p1 p2 [k3]]", min_columns=4)
    first = TextTable(table.path, table.rows[:1], table.lines[:1])
    if len(first.rows[0]) not in (4, 8, 9):
        raise first.error(0, f"expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]', got {len(first.rows[0])} values")
    return tuple(float(v) for v in first.floats(what="value")[0])


def _read_tum_list(path, what: str) -> tuple[np.ndarray, list[str]]:
    """``timestamp file`` per line (rgb.txt, depth.txt): ``(t (N,) s, relative paths)``."""
    table = read_text_table(path, Path(path).name, layout=f"timestamp {what}", min_columns=2)
    t = table.floats(slice(0, 1), what="timestamp")[:, 0]
    table.check_increasing(t, strict=False)
    names = table.column(1)
    for row, name in enumerate(names):
        if not stays_inside(name):
            raise table.error(row, f"image path {name!r} points outside the sequence folder")
    return t, names


def freiburg_camera_name(folder: Path) -> str | None:
    """``"freiburgN"`` named by the folder's own name or by ``rgb.txt``'s header, else None.

    The folder's name is taken as given (a symlink keeps its name); the header of a real
    ``rgb.txt`` names the recording (``# file: 'rgbd_dataset_freiburg1_rpy.bag'``), so a
    renamed folder is still recognised.
    """
    names = [Path(folder).name]
    rgb = Path(folder) / "rgb.txt"
    try:
        with open(rgb, encoding="utf-8", errors="replace") as fh:
            names += [line for _, line in zip(range(5), fh) if line.startswith("#")]
    except OSError:
        pass
    for text in names:
        m = _FREIBURG_RE.search(text)
        if m and f"freiburg{m.group(1)}" in TUM_CAMERAS:
            return f"freiburg{m.group(1)}"
    return None


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
    name = freiburg_camera_name(folder)
    if name is not None:
        cam = TUM_CAMERAS[name]
        if (cam.width, cam.height) != (width, height):
            cam = cam.scaled(width / cam.width, height / cam.height)
        return cam
    raise SequenceFormatError(folder, "cannot tell the camera: neither the folder name nor rgb.txt's header names a known Freiburg camera "
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
        t_rgb, rgb_rows = _read_tum_list(rgb_file, "rgb/<file>.png")
        keep = np.ones(len(t_rgb), bool)

        depth_file = folder / "depth.txt"
        depth_paths = None
        if depth_file.is_file():
            t_depth, depth_rows = _read_tum_list(depth_file, "depth/<file>.png")
            idx = associate_nearest(t_rgb, t_depth, tol)
            if not (idx >= 0).any():
                raise SequenceFormatError(depth_file, (
                    f"no depth timestamp within {tol} s of any rgb.txt timestamp "
                    f"(rgb {t_rgb[0]:.3f}..{t_rgb[-1]:.3f}, depth {t_depth[0]:.3f}..{t_depth[-1]:.3f})"))
            keep &= idx >= 0
            depth_paths = [folder / depth_rows[i] if i >= 0 else None for i in idx]

        gt_file = folder / "groundtruth.txt"
        poses = None
        if gt_file.is_file():
            t_gt, T_gt = read_tum_trajectory(gt_file)
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
        self._rgb = [folder / rgb_rows[i] for i in sel]
        self._depth = None if depth_paths is None else [depth_paths[i] for i in sel]
        self._poses = None if poses is None else poses[sel]

        acc_file = folder / "accelerometer.txt"
        self.accelerometer = None
        if acc_file.is_file():
            rows = read_text_table(acc_file, "accelerometer", layout="timestamp ax ay az", columns=4).floats()
            self.accelerometer = (rows[:, 0].copy(), rows[:, 1:].copy())

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


FORMAT = SequenceFormat(
    "tum_rgbd", _detect, TumRgbdSequence,
    "TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt, accelerometer.txt)",
)
