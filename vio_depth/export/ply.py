"""Point clouds as binary little-endian PLY: sparse metric points and dense back-projections.

Every cloud is in the sequence's WORLD frame (metres): each frame's points are moved with
its camera-to-world pose ``T_w_c``. Vertex properties, in this order:

    x y z           float   metres, world frame
    red green blue  uchar   colour of the pixel in the frame's image
    sigma_depth     float   1-sigma depth uncertainty in metres along the camera z axis
                            (sparse: triangulation; dense: from the fit's covariance);
                            NaN when unknown
    depth           float   metres, z in the observing camera
    frame           int     index of the observing frame
    inlier          uchar   1 = inlier of the frame's (alpha, beta) fit (sparse only; dense: 1)

Pixel coordinates of keypoints and depth-map pixels are RAW (distorted) pixels: they are
undistorted (:meth:`vio_core.Camera.undistort_points`) before back-projection, and colours
are read at the raw pixel. Any viewer that reads binary PLY (MeshLab, CloudCompare, Open3D,
``plyfile``) opens the files; extra properties are ignored by viewers that do not know them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import transform_points

from ..io.depth_png import write_bytes_atomic

#: (numpy dtype kind, item size) -> PLY type name
_PLY_TYPES = {
    ("f", 4): "float", ("f", 8): "double",
    ("u", 1): "uchar", ("i", 1): "char",
    ("u", 2): "ushort", ("i", 2): "short",
    ("u", 4): "uint", ("i", 4): "int",
}

VERTEX_DTYPE = np.dtype([
    ("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
    ("red", "u1"), ("green", "u1"), ("blue", "u1"),
    ("sigma_depth", "<f4"), ("depth", "<f4"), ("frame", "<i4"), ("inlier", "u1"),
])

#: colour of points when no image is given
DEFAULT_RGB = (200, 200, 200)


@dataclass
class PointCloud:
    """Points in the world frame with per-point colour and uncertainty.

    Attributes:
        points_w: (N, 3) metres, world frame.
        rgb: (N, 3) uint8.
        sigma_depth: (N,) metres, 1-sigma along the observing camera's z (NaN = unknown).
        depth: (N,) metres, z in the observing camera.
        frame: (N,) int, index of the observing frame.
        inlier: (N,) bool, inlier of that frame's fit.
    """

    points_w: np.ndarray
    rgb: np.ndarray
    sigma_depth: np.ndarray
    depth: np.ndarray
    frame: np.ndarray
    inlier: np.ndarray

    def __post_init__(self):
        p = check_array("points_w", self.points_w, (None, 3))
        n = len(p)
        check_array("rgb", self.rgb, (n, 3), dtype=None)
        check_array("sigma_depth", self.sigma_depth, (n,))
        check_array("depth", self.depth, (n,))
        check_array("frame", self.frame, (n,), dtype="int")
        check_array("inlier", self.inlier, (n,), dtype="bool")

    def __len__(self) -> int:
        return len(self.points_w)

    @classmethod
    def empty(cls) -> "PointCloud":
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0), np.zeros(0),
                   np.zeros(0, np.int64), np.zeros(0, bool))

    @classmethod
    def concatenate(cls, clouds) -> "PointCloud":
        """One cloud with the points of ``clouds`` in order."""
        clouds = list(clouds)
        if not clouds:
            return cls.empty()
        return cls(*(np.concatenate([getattr(c, f) for c in clouds]) for f in
                     ("points_w", "rgb", "sigma_depth", "depth", "frame", "inlier")))

    def to_vertices(self) -> np.ndarray:
        """(N,) structured array with :data:`VERTEX_DTYPE` (the PLY vertex record)."""
        v = np.empty(len(self), dtype=VERTEX_DTYPE)
        v["x"], v["y"], v["z"] = (self.points_w[:, k] for k in range(3))
        v["red"], v["green"], v["blue"] = (self.rgb[:, k] for k in range(3))
        v["sigma_depth"] = self.sigma_depth
        v["depth"] = self.depth
        v["frame"] = self.frame
        v["inlier"] = self.inlier
        return v


def _pixel_colours(image, uv_raw) -> np.ndarray:
    """(N, 3) uint8 colours of ``image: (H, W, 3)`` at the nearest pixel of ``uv_raw: (N, 2)``."""
    if image is None:
        return np.tile(np.asarray(DEFAULT_RGB, np.uint8), (len(uv_raw), 1))
    image = check_image("image", image, channels=3)
    h, w = image.shape[:2]
    u = np.clip(np.rint(uv_raw[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(uv_raw[:, 1]).astype(np.int64), 0, h - 1)
    return image[v, u].astype(np.uint8)


def sparse_cloud(camera: Camera, T_w_c, uv_raw, depth, *, image=None, sigma_depth=None, inlier=None,
                 frame_index: int = 0) -> PointCloud:
    """The metric points of one frame in the world frame.

    Args:
        camera: the frame's camera.
        T_w_c: (4, 4) camera-to-world pose of the frame.
        uv_raw: (N, 2) RAW pixels of the points (as in ``FrameResult.points_uv``).
        depth: (N,) metres along the camera z axis (``FrameResult.points_depth``).
        image: (H, W, 3) uint8 RGB image of the frame for the colours, or None (grey).
        sigma_depth: (N,) metres or None (NaN in the file).
        inlier: (N,) bool or None (all True).
        frame_index: stored in the ``frame`` property.
    """
    T_w_c = check_transform("T_w_c", T_w_c)
    uv_raw = check_array("uv_raw", uv_raw, (None, 2))
    n = len(uv_raw)
    depth = check_array("depth", depth, (n,))
    sigma = np.full(n, np.nan) if sigma_depth is None else check_array("sigma_depth", sigma_depth, (n,))
    inl = np.ones(n, bool) if inlier is None else check_array("inlier", inlier, (n,), dtype="bool")
    points_c = camera.backproject(camera.undistort_points(uv_raw), depth)
    return PointCloud(transform_points(T_w_c, points_c), _pixel_colours(image, uv_raw), sigma, depth.copy(),
                      np.full(n, int(frame_index), np.int64), inl.copy())


def dense_cloud(camera: Camera, T_w_c, depth_map, *, image=None, sigma_map=None, stride: int = 4,
                max_depth: float | None = None, frame_index: int = 0) -> PointCloud:
    """Back-project every ``stride``-th pixel (both directions) of a depth map into the world frame.

    Args:
        camera: the frame's camera; the depth map lies on its RAW (distorted) pixel grid.
        T_w_c: (4, 4) camera-to-world pose.
        depth_map: (H, W) metres, NaN / <= 0 invalid (skipped).
        image: (H, W, 3) uint8 RGB image for the colours, or None (grey).
        sigma_map: (H, W) metres, 1-sigma depth (e.g. ``depth_sigma_map``), or None.
        stride: pixel step >= 1 (stride 4 keeps 1/16 of the pixels).
        max_depth: drop pixels deeper than this (metres), or None.
        frame_index: stored in the ``frame`` property.
    """
    if int(stride) < 1:
        raise SettingsError(f"dense cloud stride must be >= 1, got {stride}")
    T_w_c = check_transform("T_w_c", T_w_c)
    depth_map = check_array("depth_map", depth_map, (None, None))
    h, w = depth_map.shape
    if (w, h) != (camera.width, camera.height):
        raise InputError(f"depth_map: {w}x{h} does not match the camera's {camera.width}x{camera.height}")
    vv, uu = np.mgrid[0:h:int(stride), 0:w:int(stride)]
    d = depth_map[vv, uu].astype(np.float64)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(d) & (d > 0)
        if max_depth is not None:
            keep &= d <= max_depth
    uv_raw = np.stack([uu[keep], vv[keep]], axis=1).astype(np.float64)
    sigma = None
    if sigma_map is not None:
        sigma = check_array("sigma_map", sigma_map, (h, w))[vv, uu][keep].astype(np.float64)
    return sparse_cloud(camera, T_w_c, uv_raw, d[keep], image=image, sigma_depth=sigma, frame_index=frame_index)


def encode_ply(vertices: np.ndarray, comments=()) -> bytes:
    """Binary little-endian PLY bytes of a structured array ``vertices: (N,)`` (one vertex element).

    Field types must be one of float32/64, (u)int8/16/32; field names become property names.
    """
    vertices = np.asarray(vertices)
    if vertices.dtype.names is None or vertices.ndim != 1:
        raise InputError("PLY vertices must be a 1-D structured array")
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comments]
    lines.append(f"element vertex {len(vertices)}")
    packed = []
    for name in vertices.dtype.names:
        dt = vertices.dtype.fields[name][0]
        ply_type = _PLY_TYPES.get((dt.kind, dt.itemsize))
        if ply_type is None:
            raise InputError(f"PLY property {name!r}: unsupported dtype {dt}")
        lines.append(f"property {ply_type} {name}")
        packed.append((name, dt.newbyteorder("<")))
    lines.append("end_header")
    body = vertices.astype(np.dtype(packed), copy=False).tobytes()
    return ("\n".join(lines) + "\n").encode("ascii") + body


def write_ply(path, cloud: PointCloud, comments=()) -> None:
    """Write ``cloud`` as binary little-endian PLY with :data:`VERTEX_DTYPE` properties, atomically.

    Raises:
        InputError: wrong suffix or the file cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise InputError(f"{path}: point clouds are written as .ply files")
    data = encode_ply(cloud.to_vertices(), comments=("vio-depth point cloud, world frame, metres",) + tuple(comments))
    try:
        write_bytes_atomic(path, data)
    except OSError as exc:
        raise InputError(f"{path}: cannot write PLY ({exc.strerror})") from None
