"""Microsoft 7-Scenes style folders.

A folder holding ``frame-XXXXXX.color.{jpg,png}``, ``frame-XXXXXX.depth.png`` (uint16
millimetres, 0 and 65535 = invalid), ``frame-XXXXXX.pose.txt`` (4x4 camera-to-world,
metres, from KinectFusion) and optionally ``camera-intrinsics.txt`` (3x3 K).

Two cameras (see docs/datasets.md):

* The poses and the published intrinsics (fx = fy = 585, cx = 320, cy = 240, the values
  of ``camera-intrinsics.txt``) belong to the Kinect **depth** camera: KinectFusion
  tracks the depth images.
* The **colour** camera is a different sensor, about 2.5 cm to the side, with a focal
  length of about 525 px (the value used by DSAC*/ACE for 7-Scenes). Checked on
  ``redkitchen``: the median Sampson distance of SIFT matches to the epipolar geometry
  of the pose pairs is smallest for focal lengths 510-540 px (1.1-1.4 px) and 1.8 px at
  585; triangulated points agree with the Kinect depth to a median of ~7 % with 525 px
  and ~20 % with 585 px.

The loader therefore returns colour-camera frames: ``camera`` is
:attr:`SevenScenesSettings.colour_camera`, ``T_w_c = T_w_depth T_colour_depth^-1`` and
``gt_depth()`` is the Kinect depth **re-projected into the colour camera** (nearest
surface per pixel, 0 where the depth camera sees nothing). The depth-to-colour
extrinsic is a generic Kinect v1 calibration (not this unit's), so a few pixels of
misregistration remain near depth edges: compare against it with robust statistics
(:mod:`vio_depth.evaluation.point_accuracy`). The colour and depth images are also not
synchronised (hand-held motion), which limits how well the poses fit the colour images.

Other caveats: no timestamps (frame ``k`` gets ``k / 30`` s, the Kinect's nominal
30 Hz) and no IMU (``--poses imu`` fails with "sequence has no IMU").
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import invert_transform

from ..frame import Frame
from .base import Sequence, SequenceFormat
from .depth_png import read_depth_png
from .images import read_rgb_image
from .rasterize import register_depth
from .tables import MAX_POSITION_M, read_matrix

#: nominal frame rate used to make timestamps, Hz
SEVENSCENES_FPS = 30.0
#: published 7-Scenes (depth camera) intrinsics, used when camera-intrinsics.txt is absent
SEVENSCENES_DEPTH_CAMERA = Camera(640, 480, 585.0, 585.0, 320.0, 240.0)
#: colour camera of the Kinect v1 as used for 7-Scenes by DSAC*/ACE
SEVENSCENES_COLOUR_CAMERA = Camera(640, 480, 525.0, 525.0, 320.0, 240.0)
#: depth-to-colour transform of a Kinect v1 (LIRIS Kinect calibration, as used by
#: DSAC*/ACE for 7-Scenes): maps depth-camera points into the colour camera, metres
KINECT_T_COLOUR_DEPTH = np.array([
    [9.9996518012567637e-01, 2.6765126468950343e-03, -7.9041012313000904e-03, -2.5558943178152542e-02],
    [-2.7409311281316700e-03, 9.9996302803027592e-01, -8.1504520778013286e-03, 1.0109636268061706e-04],
    [7.8819942130445332e-03, 8.1718328771890631e-03, 9.9993554558014031e-01, 2.0318321729487039e-03],
    [0.0, 0.0, 0.0, 1.0],
])
#: depth PNG units per metre
SEVENSCENES_DEPTH_SCALE = 1000.0

_COLOR_RE = re.compile(r"^(frame-\d+)\.color\.(jpg|png)$")


@dataclass(frozen=True)
class SevenScenesSettings:
    """Camera model of a 7-Scenes folder (see the module docstring).

    Attributes:
        colour_camera: intrinsics of the colour images.
        T_colour_depth: (4, 4) depth-camera-to-colour-camera transform, metres (its
            rotation is re-orthonormalised).
        register_depth: re-project the depth into the colour camera (default). False
            returns the raw depth images in the depth camera's pixel grid.
    """

    colour_camera: Camera = SEVENSCENES_COLOUR_CAMERA
    T_colour_depth: tuple = field(default=tuple(map(tuple, KINECT_T_COLOUR_DEPTH)))
    register_depth: bool = True


def read_sevenscenes_depth(path, camera: Camera | None = None) -> np.ndarray:
    """Read a 7-Scenes depth PNG (uint16 millimetres; 0 and 65535 = invalid).

    Returns (H, W) float32 metres, 0 = invalid. Raises :class:`SequenceFormatError`
    naming the file when it is unreadable, not 16-bit, or not ``camera``'s size.
    """
    depth = read_depth_png(path, SEVENSCENES_DEPTH_SCALE)
    if camera is not None and depth.shape != (camera.height, camera.width):
        raise SequenceFormatError(path, f"depth is {depth.shape[1]}x{depth.shape[0]} but the camera is "
                                        f"{camera.width}x{camera.height}")
    depth[depth == np.float32(65535) / np.float32(SEVENSCENES_DEPTH_SCALE)] = 0.0
    return depth


def _load_registered_depth(path, depth_camera: Camera, colour_camera: Camera, T_colour_depth) -> np.ndarray:
    return register_depth(read_sevenscenes_depth(path, depth_camera), depth_camera, colour_camera, T_colour_depth)


def _read_pose(path: Path) -> np.ndarray:
    T = read_matrix(path, (4, 4), "4x4 camera-to-world pose")
    if not np.all(np.abs(T[:3, 3]) <= MAX_POSITION_M):
        raise SequenceFormatError(path, f"position {T[:3, 3].tolist()} m is beyond the plausible "
                                        f"{MAX_POSITION_M:.0e} m")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise SequenceFormatError(path, f"last row must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        raise SequenceFormatError(path, "rotation block is not a rotation matrix")
    U, _, Vt = np.linalg.svd(R)  # KinectFusion poses are slightly non-orthonormal
    T = T.copy()
    T[:3, :3] = U @ Vt
    return T


def _color_frames(folder: Path) -> list[tuple[str, Path]]:
    out = []
    for p in folder.iterdir():
        m = _COLOR_RE.match(p.name)
        if m:
            out.append((m.group(1), p))
    return sorted(out)


class SevenScenesSequence(Sequence):
    """A 7-Scenes sequence folder as colour-camera frames (see the module docstring).

    Poses are read eagerly (small text files); images and depth lazily.

    Attributes:
        depth_camera: intrinsics of the Kinect depth images (camera-intrinsics.txt).
        T_colour_depth: (4, 4) depth-to-colour transform in use.
    """

    format_name = "7scenes"
    pose_kind = "kinectfusion"

    def __init__(self, path, settings: SevenScenesSettings = SevenScenesSettings()):
        folder = Path(path)
        frames = _color_frames(folder) if folder.is_dir() else []
        if not frames:
            raise InputError(f"{folder}: no frame-XXXXXX.color.jpg/png files (not a 7-Scenes folder)")
        self.settings = settings
        intr = folder / "camera-intrinsics.txt"
        depth_camera = SEVENSCENES_DEPTH_CAMERA
        if intr.is_file():
            K = read_matrix(intr, (3, 3), "3x3 intrinsics")
            try:
                # 7-Scenes images are 640x480; the principal point does not tell the size
                depth_camera = Camera.from_K(K, SEVENSCENES_DEPTH_CAMERA.width, SEVENSCENES_DEPTH_CAMERA.height)
            except InputError as e:
                raise SequenceFormatError(intr, str(e)) from None
        self.depth_camera = depth_camera
        T = np.array(settings.T_colour_depth, dtype=np.float64)
        U, _, Vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = U @ Vt
        self.T_colour_depth = check_transform("T_colour_depth", T)
        self._stems = [s for s, _ in frames]
        self._color = [p for _, p in frames]
        poses = []
        for stem in self._stems:
            pose_file = folder / f"{stem}.pose.txt"
            if not pose_file.is_file():
                raise SequenceFormatError(pose_file, "pose file missing for this colour image")
            poses.append(_read_pose(pose_file))
        self._poses = np.stack(poses) @ invert_transform(self.T_colour_depth)  # T_w_depth -> T_w_colour
        self._depth = [folder / f"{s}.depth.png" for s in self._stems]
        self._has_depth = any(p.is_file() for p in self._depth)
        super().__init__(folder, folder.name, settings.colour_camera, imu=None)

    def __len__(self) -> int:
        return len(self._stems)

    @property
    def has_gt_depth(self) -> bool:
        return self._has_depth

    def _depth_loader(self, path: Path):
        if not path.is_file():
            return None
        if self.settings.register_depth:
            return partial(_load_registered_depth, path, self.depth_camera, self.camera, self.T_colour_depth)
        return partial(read_sevenscenes_depth, path, self.depth_camera)

    def frame(self, index: int) -> Frame:
        return Frame(
            index=index,
            timestamp=index / SEVENSCENES_FPS,
            stem=self._stems[index],
            camera=self.camera,
            T_w_c=self._poses[index].copy(),
            load_image=partial(read_rgb_image, self._color[index], self.camera),
            load_gt_depth=self._depth_loader(self._depth[index]),
        )


def _detect(path: Path) -> bool:
    return path.is_dir() and any(_COLOR_RE.match(p.name) for p in path.glob("frame-*.color.*"))


FORMAT = SequenceFormat(
    "7scenes", _detect, SevenScenesSequence,
    "Microsoft 7-Scenes folder (frame-XXXXXX.color/depth/pose, camera-intrinsics.txt)",
)
