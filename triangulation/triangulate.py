"""Two-view triangulation of matched keypoints with a known metric relative pose.

Frames and conventions: ``cur`` is the current camera (the one whose depth map is
rescaled), ``ref`` the keyframe camera. ``T_ref_cur`` maps points of the current camera
frame into the reference camera frame (metres); ``x_ref^T F x_cur = 0`` for ideal
(undistorted) pixels with ``F = K_ref^-T [t]x R K_cur^-1``.

Method (all batched numpy, no per-point Python loop; steps 2 and 3 are :mod:`.epipolar`'s):

1. raw keypoints are undistorted to ideal pinhole pixels (:meth:`Camera.undistort_points`);
2. Sampson distance of every match to the epipolar geometry, in pixels;
3. optimal correction of the two observations onto the epipolar geometry (Lindstrom,
   "Triangulation made easy", CVPR 2010, ``niter2``): the smallest pixel displacement
   that makes the two viewing rays intersect, i.e. the maximum-likelihood two-view
   triangulation under isotropic Gaussian pixel noise;
4. the (now intersecting) rays are triangulated in closed form by the midpoint method;
5. checks, in this order -- a point gets the **first** failing one:

   ============  =========================================================================
   EPIPOLAR      Sampson distance > ``max_sampson_px``
   LOW_PARALLAX  angle between the two viewing rays < ``min_angle_deg``, or geometry
                 undefined (zero baseline: every point; a match sitting on both epipoles,
                 where the Sampson distance is undefined; parallel rays); checked before
                 cheirality because the depth of a low-parallax point is ill-determined
                 and may flip sign with noise
   BEHIND_CAMERA point not in front of both cameras (z <= 0 in either)
   REPROJECTION  reprojection error > ``max_reprojection_px`` in either view
   DEPTH_RANGE   depth (z in the current camera) outside [``min_depth_m``, ``max_depth_m``]
   ============  =========================================================================

   Sampson distance and reprojection error are measured in ideal (undistorted) pixels.
   After the optimal correction the reprojection error in each view equals that view's
   correction, so REPROJECTION mostly guards numerics and matters when
   ``max_sampson_px`` is relaxed. The triangulation angle is the angle between the two
   (corrected) viewing rays, which equals the angle at the point between the two camera
   centres for a point in front of both cameras.

   A point that passes every check but whose depth uncertainty is not finite (numerically
   degenerate geometry) is marked LOW_PARALLAX as well, so VALID points always have
   finite ``depth`` and ``sigma_depth``.

Depth uncertainty ``sigma_depth`` is first-order: the Jacobian of the current-camera
depth w.r.t. the four ideal pixel coordinates (and, with a pose covariance, w.r.t. the 6
pose parameters) is computed by central differences of the whole batched pipeline
(correction + triangulation; the eight perturbed pixel sets in one call, the twelve
perturbed poses in another, each pose with its own fundamental matrix), then
``var = sigma_px^2 |J_px|^2 + J_pose S J_pose^T``. It therefore captures baseline,
triangulation angle and position in the image.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SettingsError
from vio_core.settings import Presets

from .epipolar import _correct, _cross, _fundamental, _homogeneous, _rowdot, _sampson

#: baseline (metres) below which a pose is treated as a pure rotation: nothing can be
#: triangulated and every point is LOW_PARALLAX
ZERO_BASELINE_M = 1e-9

# central-difference steps of the numerical Jacobians: pixels, radians, metres
_STEP_PX = 1e-3
_STEP_ROT = 1e-6
_STEP_TRANS = 1e-6


class PointStatus(enum.IntEnum):
    """Outcome of one candidate match (see the module docstring for the check order)."""

    VALID = 0
    EPIPOLAR = 1
    BEHIND_CAMERA = 2
    REPROJECTION = 3
    LOW_PARALLAX = 4
    DEPTH_RANGE = 5


@dataclass(frozen=True)
class TriangulationSettings:
    """Thresholds of :func:`triangulate_pair`.

    Attributes:
        max_sampson_px: largest Sampson distance (first-order total geometric distance of
            the match to the epipolar geometry, ideal pixels) of an inlier. 1.5 px keeps
            SIFT matches (sub-pixel keypoints) while rejecting most wrong matches that are
            not along the epipolar line.
        max_reprojection_px: largest reprojection error of the triangulated point in
            either view (ideal pixels).
        min_angle_deg: smallest triangulation angle (between the two viewing rays). With
            pixel noise ``s`` and focal ``f`` the relative depth error is about
            ``s / (f * angle_rad)``: 1 degree gives ~8 % at f = 720 px, s = 1 px (KITTI)
            -- the rescaler is robust to that, and ``sigma_depth`` tells it which points
            are weaker; a larger threshold throws away most far points of forward motion.
        min_depth_m / max_depth_m: accepted depth range in the current camera, metres.
        pixel_sigma_px: 1-sigma keypoint noise (applied to ideal pixels, both views) used
            for ``sigma_depth``; 0 disables the pixel term.
    """

    max_sampson_px: float = 1.5
    max_reprojection_px: float = 2.0
    min_angle_deg: float = 1.0
    min_depth_m: float = 0.1
    max_depth_m: float = 300.0
    pixel_sigma_px: float = 1.0

    def __post_init__(self):
        if not (self.max_sampson_px > 0 and self.max_reprojection_px > 0):
            raise SettingsError("triangulation: max_sampson_px and max_reprojection_px must be positive")
        if not 0.0 <= self.min_angle_deg < 90.0:
            raise SettingsError(f"triangulation: min_angle_deg must be in [0, 90), got {self.min_angle_deg}")
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise SettingsError(
                f"triangulation: need 0 <= min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}"
            )
        if not self.pixel_sigma_px >= 0:
            raise SettingsError(f"triangulation: pixel_sigma_px must be >= 0, got {self.pixel_sigma_px}")


#: Named triangulation presets (``[triangulation] preset = ...`` in a config file).
TRIANGULATION_PRESETS: Presets = Presets("triangulation preset", {
    "default": TriangulationSettings(),
}, default="default", descriptions={
    "default": "Sampson 1.5 px, reprojection 2 px, angle 1 deg, depth 0.1-300 m, pixel sigma 1 px",
})


@dataclass(frozen=True)
class TriangulatedPoints:
    """All candidate matches of one frame pair, triangulated, with a status each.

    Attributes:
        points_cur: (N, 3) metres, points in the current camera frame (NaN when undefined,
            which only happens for non-VALID points).
        uv: (N, 2) raw pixels of the observation in the current image (where the
            rescaler samples the disparity).
        depth: (N,) metres, z in the current camera (finite for VALID points).
        sigma_depth: (N,) metres, first-order 1-sigma depth uncertainty.
        angle_deg: (N,) degrees, triangulation angle between the two viewing rays.
        sampson_px: (N,) ideal pixels, Sampson distance to the epipolar geometry (NaN
            where undefined: zero baseline, match on both epipoles).
        reprojection_px: (N,) ideal pixels, reprojection error, max over the two views.
        confidence: (N,) matching confidence in [0, 1] (ones when the matcher gave none).
        status: (N,) uint8 :class:`PointStatus` values.
        depth_pose_jacobian: (N, 6) metres per (rad, m): d depth / d xi of the relative
            pose's right perturbation (rotation first), or None when the pose was taken as
            exact. The pose error is shared by every point of the pair: the rescaler needs
            these rows (not only ``sigma_depth``) to know that it does not average out.
    """

    points_cur: np.ndarray
    uv: np.ndarray
    depth: np.ndarray
    sigma_depth: np.ndarray
    angle_deg: np.ndarray
    sampson_px: np.ndarray
    reprojection_px: np.ndarray
    confidence: np.ndarray
    status: np.ndarray
    depth_pose_jacobian: np.ndarray | None = None

    def __post_init__(self):
        p = check_array("points_cur", self.points_cur, (None, 3))
        n = len(p)
        check_array("uv", self.uv, (n, 2))
        for name in ("depth", "sigma_depth", "angle_deg", "sampson_px", "reprojection_px", "confidence"):
            check_array(name, getattr(self, name), (n,))
        check_array("status", self.status, (n,), dtype="int")
        if self.depth_pose_jacobian is not None:
            check_array("depth_pose_jacobian", self.depth_pose_jacobian, (n, 6))

    def __len__(self) -> int:
        return len(self.depth)

    @classmethod
    def empty(cls) -> "TriangulatedPoints":
        z = np.zeros(0)
        return cls(np.zeros((0, 3)), np.zeros((0, 2)), z, z, z, z, z, z, np.zeros(0, np.uint8))

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool: status is VALID."""
        return self.status == PointStatus.VALID

    def subset(self, mask) -> "TriangulatedPoints":
        """The points selected by ``mask``: (N,) bool, or an integer index array."""
        m = np.asarray(mask)
        if m.dtype == np.bool_ and m.shape != (len(self),):
            raise InputError(f"subset: boolean mask must have shape ({len(self)},), got {m.shape}")
        return TriangulatedPoints(
            self.points_cur[m], self.uv[m], self.depth[m], self.sigma_depth[m], self.angle_deg[m],
            self.sampson_px[m], self.reprojection_px[m], self.confidence[m], self.status[m],
            None if self.depth_pose_jacobian is None else self.depth_pose_jacobian[m],
        )

    def status_counts(self) -> dict[str, int]:
        """Number of points per status, e.g. ``{"valid": 812, "epipolar": 95, ...}`` (all statuses)."""
        counts = np.bincount(self.status.astype(np.int64), minlength=len(PointStatus))
        return {s.name.lower(): int(counts[s.value]) for s in PointStatus}


def _midpoint(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t):
    """Midpoint triangulation of ideal pixels ``uv_cur, uv_ref: (..., N, 2)`` under poses
    ``R: (..., 3, 3)``, ``t: (..., 3)`` (leading dimensions broadcast).

    Returns ``(f, g, C, fg, lam_c, lam_r)``: the viewing rays in the current frame (f: z = 1
    current rays, g: reference rays ``R^T f_ref``; (..., N, 3)), the reference camera centre
    C (..., 3) in the current frame, ``f . g`` (..., N), and the ray lengths (..., N) of the
    closest points ``lam_c f`` and ``C + lam_r g`` (NaN for parallel rays).
    """
    f = _homogeneous(uv_cur) @ K_cur_inv.T
    g = (_homogeneous(uv_ref) @ K_ref_inv.T) @ R
    C = (-np.swapaxes(R, -1, -2) @ t[..., None])[..., 0]
    ff = _rowdot(f, f)
    gg = _rowdot(g, g)
    fg = _rowdot(f, g)
    fC = (f @ C[..., None])[..., 0]
    gC = (g @ C[..., None])[..., 0]
    det = ff * gg - fg * fg  # = |f x g|^2
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_c = np.where(det > 0, (gg * fC - fg * gC) / det, np.nan)
        lam_r = np.where(det > 0, (fg * fC - ff * gC) / det, np.nan)
    return f, g, C, fg, lam_c, lam_r


def _rays_and_points(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t):
    """Midpoint triangulation of ideal pixels -> (points_cur (N, 3), cos/sin of ray angle)."""
    f, g, C, fg, lam_c, lam_r = _midpoint(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t)
    points = 0.5 * (lam_c[:, None] * f + C + lam_r[:, None] * g)
    sin = np.linalg.norm(_cross(f, g), axis=1)
    return points, fg, sin


def _depth(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t):
    """(..., N) depth (z in the current camera) of corrected, midpoint-triangulated ideal
    pixels ``uv_cur, uv_ref: (..., N, 2)`` under poses ``R: (..., 3, 3)``, ``t: (..., 3)``."""
    F = _fundamental(R, t, K_cur_inv, K_ref_inv)
    c_cur, c_ref = _correct(F, uv_cur, uv_ref)
    f, g, C, _, lam_c, lam_r = _midpoint(c_cur, c_ref, K_cur_inv, K_ref_inv, R, t)
    return 0.5 * (lam_c * f[..., 2] + C[..., None, 2] + lam_r * g[..., 2])


def _depth_jacobian_pixels(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t) -> np.ndarray:
    """(N, 4) d depth / d (u_cur, v_cur, u_ref, v_ref), central differences in one batch."""
    n = len(uv_cur)
    cur = np.tile(uv_cur, (8, 1))
    ref = np.tile(uv_ref, (8, 1))
    for k in range(4):  # 4 coordinates x (+h, -h): blocks of n rows
        for s, sign in enumerate((1.0, -1.0)):
            rows = slice((2 * k + s) * n, (2 * k + s + 1) * n)
            target = cur if k < 2 else ref
            target[rows, k % 2] += sign * _STEP_PX
    z = _depth(cur, ref, K_cur_inv, K_ref_inv, R, t).reshape(4, 2, n)
    return ((z[:, 0] - z[:, 1]) / (2.0 * _STEP_PX)).T


#: (6,) central-difference step of each pose tangent axis (rotation rad, then translation m)
_POSE_STEP = np.array([_STEP_ROT] * 3 + [_STEP_TRANS] * 3)


def _pose_steps() -> np.ndarray:
    """(12, 6): the tangent-space perturbations of the pose Jacobian, +h then -h per axis."""
    axis = np.arange(6)
    xi = np.zeros((6, 2, 6))
    xi[axis, 0, axis] = _POSE_STEP
    xi[axis, 1, axis] = -_POSE_STEP
    return xi.reshape(12, 6)


_POSE_STEPS = _pose_steps()
#: (12, 3, 3) ``Exp`` of the rotation part of each perturbation (constants: computed once)
_POSE_STEP_ROTATIONS = Rotation.from_rotvec(_POSE_STEPS[:, :3]).as_matrix()


def _depth_jacobian_pose(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R, t) -> np.ndarray:
    """(N, 6) d depth / d xi for ``T_ref_cur * Exp(xi)``, ``xi = (rotation rad, translation m)``.

    First order, ``T * Exp(xi)`` has rotation ``R Exp(w)`` and translation ``t + R rho``
    (the GTSAM ``Pose3`` retraction convention). Central differences: the twelve perturbed
    poses (+h, -h per axis) are triangulated in one batched call.
    """
    R_p = R @ _POSE_STEP_ROTATIONS  # (12, 3, 3)
    t_p = t + (R @ _POSE_STEPS[:, 3:, None])[..., 0]  # (12, 3)
    z = _depth(uv_cur, uv_ref, K_cur_inv, K_ref_inv, R_p, t_p)
    z = z.reshape(6, 2, z.shape[-1])  # (axis, +h / -h, N)
    return ((z[:, 0] - z[:, 1]) / (2.0 * _POSE_STEP[:, None])).T


def triangulate_pair(
    uv_cur,
    uv_ref,
    camera_cur: Camera,
    camera_ref: Camera,
    T_ref_cur,
    settings: TriangulationSettings,
    confidence=None,
    pose_covariance=None,
) -> TriangulatedPoints:
    """Triangulate matched keypoints of the current and reference images.

    Args:
        uv_cur: (N, 2) raw (distorted) pixels of the matches in the current image.
        uv_ref: (N, 2) raw pixels of the same matches in the reference image.
        camera_cur, camera_ref: intrinsics (and distortion) of the two images.
        T_ref_cur: (4, 4) current-camera-to-reference-camera transform, metres
            (:attr:`vio_depth.poses.RelativePose.T_kf_cur`).
        settings: thresholds, see :class:`TriangulationSettings`.
        confidence: (N,) matching confidence in [0, 1], or None (ones).
        pose_covariance: (6, 6) covariance of the tangent-space error of ``T_ref_cur``
            (rotation rad first, then translation m; right perturbation
            ``T_ref_cur * Exp(xi)`` as in GTSAM), or None (pose taken as exact).

    Returns:
        :class:`TriangulatedPoints` with **every** candidate and its :class:`PointStatus`
        (module docstring: order of the checks). Never raises for degenerate geometry
        (N = 0, zero baseline, parallel rays): those become statuses.

    Raises:
        ShapeError: wrongly shaped or non-finite inputs.
    """
    uv_cur = check_array("uv_cur", uv_cur, (None, 2), finite=True).astype(np.float64)
    n = len(uv_cur)
    uv_ref = check_array("uv_ref", uv_ref, (n, 2), finite=True).astype(np.float64)
    T = check_transform("T_ref_cur", T_ref_cur)
    if not isinstance(camera_cur, Camera) or not isinstance(camera_ref, Camera):
        raise InputError("triangulate_pair: camera_cur and camera_ref must be vio_core.Camera")
    if not isinstance(settings, TriangulationSettings):
        raise InputError("triangulate_pair: settings must be a TriangulationSettings")
    conf = np.ones(n) if confidence is None else check_array("confidence", confidence, (n,), finite=True)
    cov = None if pose_covariance is None else check_array("pose_covariance", pose_covariance, (6, 6), finite=True)
    if n == 0:
        return TriangulatedPoints.empty()

    R, t = T[:3, :3], T[:3, 3]
    K_cur_inv, K_ref_inv = np.linalg.inv(camera_cur.K), np.linalg.inv(camera_ref.K)
    ic = camera_cur.undistort_points(uv_cur)
    ir = camera_ref.undistort_points(uv_ref)

    nan = np.full(n, np.nan)
    status = np.full(n, PointStatus.VALID, np.uint8)

    def mark(bad, code):
        status[(status == PointStatus.VALID) & bad] = code

    if np.linalg.norm(t) < ZERO_BASELINE_M:
        # pure rotation: epipolar geometry undefined, nothing can be triangulated
        _, cos, sin = _rays_and_points(ic, ir, K_cur_inv, K_ref_inv, R, t)
        status[:] = PointStatus.LOW_PARALLAX
        return TriangulatedPoints(np.full((n, 3), np.nan), uv_cur, nan, nan.copy(),
                                  np.degrees(np.arctan2(sin, cos)), nan.copy(), nan.copy(), conf, status)

    F = _fundamental(R, t, K_cur_inv, K_ref_inv)
    sampson = _sampson(F, _homogeneous(ic), _homogeneous(ir))
    c_cur, c_ref = _correct(F, ic, ir)
    points, cos, sin = _rays_and_points(c_cur, c_ref, K_cur_inv, K_ref_inv, R, t)
    angle = np.degrees(np.arctan2(sin, cos))
    depth = points[:, 2]
    depth_ref = points @ R[2] + t[2]

    with np.errstate(invalid="ignore", divide="ignore"):
        proj_cur = points @ camera_cur.K.T
        proj_cur = proj_cur[:, :2] / proj_cur[:, 2:]
        proj_ref = (points @ R.T + t) @ camera_ref.K.T
        proj_ref = proj_ref[:, :2] / proj_ref[:, 2:]
        reproj = np.maximum(np.linalg.norm(proj_cur - ic, axis=1), np.linalg.norm(proj_ref - ir, axis=1))

        mark(sampson > settings.max_sampson_px, PointStatus.EPIPOLAR)
        mark(~(angle >= settings.min_angle_deg) | ~np.isfinite(sampson) | ~np.isfinite(depth)
             | ~np.isfinite(depth_ref), PointStatus.LOW_PARALLAX)
        mark(~((depth > 0) & (depth_ref > 0)), PointStatus.BEHIND_CAMERA)
        mark(~(reproj <= settings.max_reprojection_px), PointStatus.REPROJECTION)
        mark(~((depth >= settings.min_depth_m) & (depth <= settings.max_depth_m)), PointStatus.DEPTH_RANGE)

    var = np.zeros(n)
    if settings.pixel_sigma_px > 0:
        J_px = _depth_jacobian_pixels(ic, ir, K_cur_inv, K_ref_inv, R, t)
        var = var + settings.pixel_sigma_px**2 * np.sum(J_px**2, axis=1)
    J_pose = None
    if cov is not None:
        J_pose = _depth_jacobian_pose(ic, ir, K_cur_inv, K_ref_inv, R, t)
        var = var + np.einsum("ni,ij,nj->n", J_pose, cov, J_pose)
        mark(~np.all(np.isfinite(J_pose), axis=1), PointStatus.LOW_PARALLAX)
        J_pose = np.where(np.isfinite(J_pose), J_pose, 0.0)
    sigma = np.sqrt(np.maximum(var, 0.0))
    mark(~np.isfinite(sigma), PointStatus.LOW_PARALLAX)

    return TriangulatedPoints(points, uv_cur, depth, sigma, angle, sampson, reproj, conf, status, J_pose)
