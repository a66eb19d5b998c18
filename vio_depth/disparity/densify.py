"""SIMULATED affine-invariant disparity for real sequences, made from their ground-truth depth.

KITTI raw and 7-Scenes come with metric ground-truth depth but without Depth Anything
predictions (and no network weights are available offline here). To evaluate the dense
rescaled depth on them anyway, :class:`~vio_depth.disparity.SimulatedDisparitySource` with
``densify`` set builds a stand-in:

1. **densify** the frame's ground-truth depth (:func:`densify_depth`): KITTI's projected
   LiDAR covers ~4 % of the pixels (~19k of 466k), 7-Scenes' Kinect depth has holes and
   uncovered borders. Holes are filled inside the **convex hull of the valid pixels** by
   ``"linear"`` interpolation (barycentric on a Delaunay triangulation of the valid pixels
   that border a hole or the image edge; a valid pixel keeps its value) or by the
   ``"nearest"`` valid pixel.
   Pixels outside the hull -- above the LiDAR's vertical field of view on KITTI, the image
   borders the depth camera does not see on 7-Scenes -- stay invalid;
2. **simulate** the disparity of the densified depth with the bundled samples' model,
   :func:`vio_depth.disparity.simulation.simulate_disparity` (softened edges, smooth
   multiplicative distortion, a random per-frame scale and shift, pixel noise), seeded
   with ``(seed, frame.index)``. So that the edge blur does not see an artificial jump at
   the hull boundary, the model is given the hull's depth extended outwards by nearest
   neighbour; the pixels outside the hull are then set to **NaN** in the returned map
   (the pipeline samples no disparity there, the evaluation has no ground truth there);
3. optionally, with ``max_hole_px``, pixels farther than that from any valid ground-truth
   pixel are left NaN as well (default: fill every hole inside the hull).

What this is and is not. The output is **SIMULATED** (``kind = "simulated"``): it is
affine in the ground truth's disparity up to the model's documented imperfections, so the
dense metrics measured with it say how well the *points* (matcher, triangulation, robust
fit) recover the per-frame scale and shift -- not how good Depth Anything is on that
data. Interpolated depth inherits the flaws of its ground truth: LiDAR points of the
background seen past a foreground edge (the LiDAR sits above the camera) and 7-Scenes'
misregistered depth edges are interpolated like any other pixel.

Measured (seed 0, default settings): with the simulation's true per-frame alpha and beta,
the median ``|D - z_gt| / z_gt`` at the ground-truth pixels is 1.2-1.8 % per frame on
kitti_tiny (7 frames) and 0.7-1.2 % on 7-Scenes redkitchen (frames 0-120, every 20th);
the least-squares "oracle" rescaling reaches AbsRel 0.041 / delta1 0.946 on kitti_tiny
(edge blur around LiDAR points seen past foreground edges dominates) and 0.011 / 0.998 on
7-Scenes (see docs/benchmarks.md, "Matchers"). One call takes ~0.35 s per KITTI frame and
~0.25 s per 7-Scenes frame on a 2-core CPU, loading the ground truth included.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import Delaunay, QhullError

from vio_core.checks import check_array
from vio_core.errors import SettingsError, UnknownNameError

from .simulation import DisparitySimulation, SimulatedDisparity, disparity_preset, simulate_disparity

#: hole-filling methods of :func:`densify_depth`
FILL_METHODS = ("linear", "nearest")


@dataclass(frozen=True)
class GtDisparitySettings:
    """How :func:`simulate_gt_disparity` densifies sparse or holey ground truth before simulating.

    Attributes:
        fill: hole filling inside the convex hull of the valid ground truth, one of
            :data:`FILL_METHODS`: ``"linear"`` (Delaunay barycentric interpolation, the
            default) or ``"nearest"`` (value of the nearest valid pixel).
        max_hole_px: pixels farther than this (pixels, Euclidean) from the nearest valid
            ground-truth pixel stay NaN; None (default) fills every hole inside the hull.
        model: parameters of the SIMULATED disparity model (default: its "default" preset,
            the one the bundled samples use).
    """

    fill: str = "linear"
    max_hole_px: float | None = None
    model: DisparitySimulation = field(default_factory=lambda: disparity_preset("default"))

    def __post_init__(self):
        if self.fill not in FILL_METHODS:
            raise UnknownNameError("depth fill method", self.fill, FILL_METHODS)
        if self.max_hole_px is not None and not self.max_hole_px > 0:
            raise SettingsError(f"max_hole_px must be positive or None, got {self.max_hole_px!r}")
        if not isinstance(self.model, DisparitySimulation):
            raise SettingsError(f"model must be a DisparitySimulation, got {type(self.model).__name__}")


def valid_depth_mask(depth) -> np.ndarray:
    """(H, W) bool: pixels of ``depth: (H, W) metres`` that are finite and > 0."""
    d = check_array("depth", depth, (None, None))
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 0)


def convex_hull_mask(valid) -> np.ndarray:
    """(H, W) bool: pixels in the convex hull of the True pixels of ``valid: (H, W) bool``.

    The hull polygon is rasterised with OpenCV (``fillConvexPoly``), which also marks pixels
    its boundary touches: up to about one pixel outside the exact hull. All False when
    ``valid`` has no True pixel.
    """
    valid = check_array("valid", valid, (None, None), dtype="bool")
    mask = np.zeros(valid.shape, np.uint8)
    rows, cols = np.nonzero(valid)
    if len(rows) == 0:
        return mask.astype(bool)
    pts = np.stack([cols, rows], axis=1).astype(np.int32)
    hull = cv2.convexHull(pts)
    cv2.fillConvexPoly(mask, hull, 1)
    return mask.astype(bool)


def _border_pixels(valid: np.ndarray) -> np.ndarray:
    """Valid pixels with an invalid (or out-of-image) pixel among their 8 neighbours.

    Every vertex of the convex hull of the valid pixels is one of them, so triangulating
    only these covers the same hull with far fewer points on dense ground truth (7-Scenes:
    ~12k instead of ~220k). On sparse LiDAR every valid pixel is one of them. The result is
    a piecewise-linear fill of the holes from their rims; it can differ from a
    triangulation of *all* valid pixels where a triangle spans valid pixels (measured on
    7-Scenes frame 2: 1.3 % of the filled pixels differ by more than 1 %).
    """
    interior = ndimage.binary_erosion(valid, structure=np.ones((3, 3), bool), border_value=0)
    return valid & ~interior


def _linear_fill(depth: np.ndarray, valid: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Barycentric interpolation on the Delaunay triangulation of the hole-border pixels.

    Args:
        depth: (H, W) metres.
        valid: (H, W) bool, pixels with ground truth.
        holes: (H, W) bool, pixels to fill.

    Returns:
        (H, W) float64 metres at the ``holes`` pixels inside a triangle, NaN elsewhere.

    Only the triangulation comes from scipy (qhull). Point location and barycentric
    weights are computed here by rasterising every triangle's bounding box (vectorised):
    scipy's ``find_simplex`` / ``griddata`` first compute per-simplex barycentric transforms
    with one LAPACK call per triangle, which took from 0.1 s to over a minute per KITTI
    frame on this shared 2-core machine (OpenBLAS threads competing with torch's).
    """
    out = np.full(depth.shape, np.nan)
    border = _border_pixels(valid)
    rows, cols = np.nonzero(border)
    if len(rows) < 3:
        return out
    pts = np.stack([cols, rows], axis=1).astype(np.float64)
    try:
        simplices = Delaunay(pts).simplices
    except QhullError:  # all border pixels collinear: no triangle to interpolate in
        return out
    p0, p1, p2 = pts[simplices[:, 0]], pts[simplices[:, 1]], pts[simplices[:, 2]]  # (T, 2) each
    e1, e2 = p1 - p0, p2 - p0
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    keep = np.abs(det) > 1e-9  # drop degenerate (flat) triangles
    p0, e1, e2, det, simplices = p0[keep], e1[keep], e2[keep], det[keep], simplices[keep]
    corners = np.stack([p0, p0 + e1, p0 + e2], axis=1)  # (T, 3, 2)
    lo = np.ceil(corners.min(axis=1)).astype(np.int64)  # integer pixel bounding boxes
    hi = np.floor(corners.max(axis=1)).astype(np.int64)
    size = np.maximum(hi - lo + 1, 0)  # (T, 2): width, height
    count = size[:, 0] * size[:, 1]
    tri_id = np.repeat(np.arange(len(count)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    px = lo[tri_id, 0] + local % size[tri_id, 0]
    py = lo[tri_id, 1] + local // size[tri_id, 0]
    want = holes[py, px]
    tri_id, px, py = tri_id[want], px[want], py[want]
    dx = px - p0[tri_id, 0]
    dy = py - p0[tri_id, 1]
    l1 = (dx * e2[tri_id, 1] - dy * e2[tri_id, 0]) / det[tri_id]
    l2 = (e1[tri_id, 0] * dy - e1[tri_id, 1] * dx) / det[tri_id]
    l0 = 1.0 - l1 - l2
    eps = -1e-9
    inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    z = depth[rows, cols].astype(np.float64)[simplices[tri_id[inside]]]  # (K, 3)
    # a pixel on an edge shared by two triangles is written twice with the same value
    out[py[inside], px[inside]] = z[:, 0] * l0[inside] + z[:, 1] * l1[inside] + z[:, 2] * l2[inside]
    return out


def densify_depth(depth, fill: str = "linear", max_hole_px: float | None = None) -> np.ndarray:
    """Fill the holes of a ground-truth depth map inside the convex hull of its valid pixels.

    Args:
        depth: (H, W) metres, ground-truth z-depth; 0, negative or NaN = invalid.
        fill: one of :data:`FILL_METHODS` (see :class:`GtDisparitySettings`).
        max_hole_px: pixels farther than this from the nearest valid pixel stay NaN
            (None: no limit).

    Returns:
        (H, W) float64 metres: valid input pixels unchanged, holes inside the convex hull
        (:func:`convex_hull_mask`) filled, NaN outside it (and beyond ``max_hole_px``). With
        ``"linear"``, the few hull pixels no triangle covers (on the rasterised hull
        boundary) take the nearest valid value. All NaN without valid pixels.

    Raises:
        UnknownNameError: unknown ``fill``.
        ShapeError: ``depth`` is not (H, W).
    """
    d = check_array("depth", depth, (None, None)).astype(np.float64)
    if fill not in FILL_METHODS:
        raise UnknownNameError("depth fill method", fill, FILL_METHODS)
    valid = valid_depth_mask(d)
    out = np.full(d.shape, np.nan)
    if not valid.any():
        return out
    out[valid] = d[valid]
    hull = convex_hull_mask(valid)
    holes = hull & ~valid
    distance, (near_r, near_c) = ndimage.distance_transform_edt(~valid, return_indices=True)
    if max_hole_px is not None:
        holes &= distance <= max_hole_px
    if not holes.any():
        return out
    nearest = d[near_r[holes], near_c[holes]]
    if fill == "linear":
        values = _linear_fill(d, valid, holes)[holes]
        # Hull pixels the triangulation misses (rounding on the hull boundary, degenerate
        # hulls) take the nearest valid value.
        values = np.where(np.isfinite(values), values, nearest)
    else:
        values = nearest
    out[holes] = values
    return out


@dataclass(frozen=True)
class GtSimulation(SimulatedDisparity):
    """One frame's SIMULATED disparity (:class:`SimulatedDisparity`: ``disparity``, ``scale``,
    ``shift`` and the true ``alpha``/``beta``) plus the densified ground truth it was made from.

    ``disparity`` is NaN where the densified ground truth is undefined (outside the convex
    hull / beyond ``max_hole_px``); ``dense_depth`` is (H, W) float64 metres, NaN there too.
    """

    dense_depth: np.ndarray


def simulate_gt_disparity(depth, seed: int, frame_index: int,
                          settings: GtDisparitySettings | None = None) -> GtSimulation | None:
    """SIMULATED disparity of one frame from its (sparse or holey) ground-truth depth.

    Args:
        depth: (H, W) metres, ground-truth z-depth; 0, negative or NaN = invalid.
        seed: non-negative sequence seed.
        frame_index: non-negative frame index (with ``seed`` it seeds the frame's RNG).
        settings: see :class:`GtDisparitySettings` (default: its defaults).

    Returns:
        :class:`GtSimulation`, or None when ``depth`` has no valid pixel.
    """
    settings = GtDisparitySettings() if settings is None else settings
    dense = densify_depth(depth, settings.fill, settings.max_hole_px)
    defined = np.isfinite(dense)
    if not defined.any():
        return None
    # The model sees the defined region extended by nearest neighbour, so its edge blur
    # does not treat the hull boundary as a jump to infinity (sky); see the module docstring.
    _, (near_r, near_c) = ndimage.distance_transform_edt(~defined, return_indices=True)
    extended = dense[near_r, near_c]
    sim: SimulatedDisparity = simulate_disparity(extended, seed, frame_index, settings.model)
    disparity = sim.disparity.copy()
    disparity[~defined] = np.nan
    return GtSimulation(disparity, sim.scale, sim.shift, dense_depth=dense)
