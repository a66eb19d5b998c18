"""N-view triangulation of feature tracks with known metric poses and their uncertainty.

Observations come flat, one row per (track, view) pair, so that every track of a window
is triangulated in one batch (no per-track Python loop):

* ``track: (M,)`` int, the track of each observation (any non-negative ids);
* ``view: (M,)`` int, index into the per-view poses ``T_w_c: (V, 4, 4)`` (camera-to-world,
  metres) and cameras;
* ``uv: (M, 2)`` raw (distorted) pixels.

Method, per track, all batched numpy:

1. raw pixels are undistorted to ideal pinhole pixels (:meth:`Camera.undistort_points`);
2. **linear N-view** initialisation: the point nearest to all viewing rays in the least
   squares sense, ``sum_i |(I - f_i f_i^T)(X - c_i)|^2`` (``f_i`` unit ray, ``c_i`` camera
   centre), solved once unweighted and once with weights ``1 / |X - c_i|^2`` (which makes
   the cost the sum of squared ray angles, a proxy of the reprojection error);
3. **Gauss-Newton on the reprojection error**, each observation whitened by its 2x2
   covariance ``S_i = sigma_px^2 I + J_pose,i Sigma_i J_pose,i^T``: the pixel noise plus the
   image motion that the view's pose uncertainty ``Sigma_i`` (6x6) can cause. Steps that do
   not lower a track's cost are rejected;
4. **outlier rounds**: an observation whose whitened residual exceeds
   ``max_residual_sigmas`` is dropped (the worst one per track per round) and the track
   re-solved; a track needs two inlier views. The gate therefore widens by itself where
   the poses are uncertain, instead of a fixed pixel threshold;
5. covariance ``Sigma_X = H^-1`` (``H = sum J_X^T S^-1 J_X`` over inliers), and for every
   observation the depth (camera z) in its own view with a first-order sigma that keeps
   the correlation between the point and that view's pose (the point was estimated from
   it: a common error partly cancels)::

       var(z_i) = a^T H^-1 a + b^T Sigma_i b + 2 a^T H^-1 J_X,i^T S_i^-1 J_pose,i Sigma_i b

   with ``a = dz_i/dX`` and ``b = dz_i/dxi_i``.

Pose errors of different views are treated as independent (the caller passes marginal
covariances); pose perturbations follow GTSAM: ``T_w_c * Exp(xi)``, ``xi = (rotation rad,
translation m)`` in the camera frame.

Statuses, first failing one wins:

==============  ========================================================================
TOO_FEW_VIEWS   fewer than two observations
LOW_PARALLAX    numerically degenerate: the rays are (nearly) parallel, the normal
                equations are singular, or the depth uncertainty is not finite
REPROJECTION    fewer than two observations left inside the residual gate
BEHIND_CAMERA   the point is not in front of every inlier view
DEPTH_RANGE     depth in an inlier view outside [``min_depth_m``, ``max_depth_m``]
UNCERTAIN       predicted relative depth sigma ``sigma_z / z`` above
                ``max_relative_sigma`` in some inlier view -- the honest replacement of a
                parallax-angle threshold: it accounts for baseline, depth, position in
                the image, pixel noise and pose uncertainty together
==============  ========================================================================
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import InputError, SettingsError

from .batched import finite, inv2, inv3, quad2, solve3, sum_by
from .jacobians import depth_variance, image_pose_jacobian, normal_terms, point_jacobian, pose_jacobian, sandwich2

# numerical floor on the largest angle between a track's rays (degrees): below it the
# geometry is treated as degenerate whatever the stated uncertainties say
_MIN_ANGLE_DEG = 1e-3
_GN_ITERATIONS = 6
_EYE3 = np.eye(3)


class TrackStatus(enum.IntEnum):
    """Outcome of one track (module docstring: order of the checks)."""

    VALID = 0
    TOO_FEW_VIEWS = 1
    LOW_PARALLAX = 2
    REPROJECTION = 3
    BEHIND_CAMERA = 4
    DEPTH_RANGE = 5
    UNCERTAIN = 6


@dataclass(frozen=True)
class MultiviewSettings:
    """Thresholds of :func:`triangulate_tracks`.

    Attributes:
        pixel_sigma_px: 1-sigma keypoint noise in ideal pixels (both axes).
        max_residual_sigmas: an observation is an inlier when its whitened reprojection
            residual ``sqrt(r^T S^-1 r)`` is at most this (3.0 keeps 99 % of Gaussian
            2-d residuals).
        outlier_rounds: rounds of dropping the worst outlier per track.
        max_relative_sigma: largest predicted ``sigma_z / z`` of a VALID track in any of
            its inlier views. 0.1 keeps points whose depth is known to 10 % (the
            rescaler weights them by their sigma anyway); it is unit-free, so the same
            value serves a room and a street.
        min_depth_m / max_depth_m: accepted depth range in every inlier view, metres.
    """

    pixel_sigma_px: float = 1.0
    max_residual_sigmas: float = 3.0
    outlier_rounds: int = 3
    max_relative_sigma: float = 0.1
    min_depth_m: float = 0.05
    max_depth_m: float = 1000.0

    def __post_init__(self):
        if not self.pixel_sigma_px > 0:
            raise SettingsError(f"multiview: pixel_sigma_px must be > 0, got {self.pixel_sigma_px}")
        if not self.max_residual_sigmas > 0 or not self.max_relative_sigma > 0:
            raise SettingsError("multiview: max_residual_sigmas and max_relative_sigma must be > 0")
        if self.outlier_rounds < 0:
            raise SettingsError(f"multiview: outlier_rounds must be >= 0, got {self.outlier_rounds}")
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise SettingsError(f"multiview: need 0 <= min_depth_m < max_depth_m, got "
                                f"{self.min_depth_m}, {self.max_depth_m}")


@dataclass(frozen=True)
class MultiviewPoints:
    """Triangulated tracks (rows ``T``) and their observations (rows ``M``, input order).

    Attributes:
        track_ids: (T,) int, the distinct input track ids, sorted.
        points_w: (T, 3) metres, world points (NaN where undefined).
        covariance_w: (T, 3, 3) square metres, covariance of each point (NaN where undefined).
        status: (T,) uint8 :class:`TrackStatus`.
        n_inliers: (T,) int, inlier observations.
        max_angle_deg: (T,) degrees, largest angle between two inlier rays.
        obs_track: (M,) int, row in the track arrays of each observation.
        inlier: (M,) bool, observation used in the estimate.
        residual_px: (M,) ideal pixels, reprojection error of each observation.
        depth: (M,) metres, camera z of the point in the observation's view.
        sigma_depth: (M,) metres, first-order 1-sigma of that depth (module docstring).
        relative_sigma: (T,) largest ``sigma_depth / depth`` over the track's inlier views
            (inf where undefined).
    """

    track_ids: np.ndarray
    points_w: np.ndarray
    covariance_w: np.ndarray
    status: np.ndarray
    n_inliers: np.ndarray
    max_angle_deg: np.ndarray
    obs_track: np.ndarray
    inlier: np.ndarray
    residual_px: np.ndarray
    depth: np.ndarray
    sigma_depth: np.ndarray
    relative_sigma: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(T,) bool: track status is VALID."""
        return self.status == TrackStatus.VALID

    def status_counts(self) -> dict[str, int]:
        """Tracks per status, e.g. ``{"valid": 812, "uncertain": 95, ...}`` (all statuses)."""
        counts = np.bincount(self.status.astype(np.int64), minlength=len(TrackStatus))
        return {s.name.lower(): int(counts[s.value]) for s in TrackStatus}


def _rotation_blocks(T_w_c: np.ndarray):
    R_wc = T_w_c[:, :3, :3]
    c_w = T_w_c[:, :3, 3]
    return np.transpose(R_wc, (0, 2, 1)), c_w


def _project(R_cw, d_w, fx, fy, cx, cy, ideal):
    """Camera points ``R_cw d_w`` (M, 3) and ideal-pixel residuals (M, 2) of observations at
    ``ideal`` (M, 2). Every value is computed row by row: the same whichever other rows come
    along (the Gauss-Newton loop relies on it)."""
    p_c = np.einsum("nij,nj->ni", R_cw, d_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = np.column_stack([fx * p_c[:, 0] / p_c[:, 2] + cx, fy * p_c[:, 1] / p_c[:, 2] + cy])
    return p_c, proj - ideal


def _linear_points(t, rays_w, centres, w, n_tracks):
    """Least-squares nearest point to weighted unit rays: (T, 3) and (T,) bool solvable.

    Normal equations ``sum w (I - f f^T) X = sum w (I - f f^T) c``, summed as
    ``(sum w) I - sum w f f^T`` and ``sum w (c - f (f . c))``."""
    wf = w[:, None] * rays_w
    A = sum_by(t, wf[:, :, None] * rays_w[:, None, :], n_tracks)
    A = np.bincount(t, weights=w, minlength=n_tracks)[:, None, None] * _EYE3 - A
    b = sum_by(t, w[:, None] * centres - wf * np.einsum("nj,nj->n", rays_w, centres)[:, None], n_tracks)
    return solve3(A, b)


def triangulate_tracks(track, view, uv, cameras, T_w_c, settings: MultiviewSettings = MultiviewSettings(),
                       pose_covariance=None) -> MultiviewPoints:
    """Triangulate feature tracks seen in several views with known metric poses.

    Args:
        track: (M,) int >= 0, track id of each observation.
        view: (M,) int in [0, V), view of each observation (index into ``T_w_c``).
        uv: (M, 2) raw (distorted) pixels of each observation.
        cameras: one :class:`Camera` for all views, or a sequence of V cameras.
        T_w_c: (V, 4, 4) camera-to-world poses, metres.
        settings: :class:`MultiviewSettings`.
        pose_covariance: (V, 6, 6) marginal covariance of each view's pose (right
            perturbation ``T_w_c * Exp(xi)``, rotation rad first, then metres), or None
            (exact poses).

    Returns:
        :class:`MultiviewPoints`. Never raises for degenerate geometry: those are statuses.

    Raises:
        ShapeError / InputError: malformed inputs (shapes, a view index out of range,
            two observations of one track in the same view).
    """
    track = check_array("track", track, (None,), dtype="int").astype(np.int64)
    m = len(track)
    view = check_array("view", view, (m,), dtype="int").astype(np.int64)
    uv = check_array("uv", uv, (m, 2), finite=True).astype(np.float64)
    T_w_c = check_array("T_w_c", T_w_c, (None, 4, 4), finite=True)
    n_views = len(T_w_c)
    cams = [cameras] * n_views if isinstance(cameras, Camera) else list(cameras)
    if len(cams) != n_views or not all(isinstance(c, Camera) for c in cams):
        raise InputError(f"triangulate_tracks: need one Camera or {n_views} cameras")
    cov = None if pose_covariance is None else check_array("pose_covariance", pose_covariance,
                                                            (n_views, 6, 6), finite=True)
    if m and (view.min() < 0 or view.max() >= n_views or track.min() < 0):
        raise InputError("triangulate_tracks: view indices must be in [0, V) and track ids >= 0")
    track_ids, t = np.unique(track, return_inverse=True)
    n_tracks = len(track_ids)
    if m and len(np.unique(t * n_views + view)) != m:
        raise InputError("triangulate_tracks: a track has two observations in the same view")

    s = settings
    # ideal pixels and per-observation camera constants
    ideal = np.empty_like(uv)
    fx, fy, cx, cy = (np.empty(m) for _ in range(4))
    for v in np.unique(view) if m else []:
        sel = view == v
        cam = cams[v]
        ideal[sel] = cam.undistort_points(uv[sel])
        fx[sel], fy[sel], cx[sel], cy[sel] = cam.fx, cam.fy, cam.cx, cam.cy
    R_cw_all, c_all = _rotation_blocks(T_w_c)
    R_cw, centres = R_cw_all[view], c_all[view]
    rays_c = np.column_stack([(ideal[:, 0] - cx) / fx, (ideal[:, 1] - cy) / fy, np.ones(m)])
    rays_w = np.einsum("nji,nj->ni", R_cw, rays_c)  # R_wc @ ray
    rays_w /= np.linalg.norm(rays_w, axis=1, keepdims=True)

    n_obs = np.bincount(t, minlength=n_tracks)
    inlier = n_obs[t] >= 2
    status = np.full(n_tracks, TrackStatus.VALID, np.uint8)
    status[n_obs < 2] = TrackStatus.TOO_FEW_VIEWS

    def mark(bad, code):
        status[(status == TrackStatus.VALID) & bad] = code

    # --- linear initialisation (unweighted, then angular weights)
    X, ok = _linear_points(t, rays_w, centres, inlier.astype(float), n_tracks)
    dist2 = np.sum((X[t] - centres) ** 2, axis=1)
    w = np.where(inlier & np.isfinite(dist2) & (dist2 > 0), 1.0 / np.where(dist2 > 0, dist2, 1.0), 0.0)
    X2, ok2 = _linear_points(t, rays_w, centres, w, n_tracks)
    X = np.where(ok2[:, None], X2, X)
    mark(~(ok | ok2), TrackStatus.LOW_PARALLAX)
    # rays that meet behind every camera: no point in front can explain them
    z_lin = np.einsum("nj,nj->n", X[t] - centres, R_cw[:, 2, :])
    mark(sum_by(t, (inlier & (z_lin > 0)).astype(float), n_tracks) == 0, TrackStatus.BEHIND_CAMERA)

    # whitening of each observation: pixel noise + image motion from pose uncertainty
    cov_v = None if cov is None else cov[view]

    def obs_info(p_c, o=slice(None)):
        """Whitening and pose Jacobians of the observations ``o``."""
        S = np.zeros((len(p_c), 2, 2))
        J_pose = None
        if cov is not None:
            J_pose = image_pose_jacobian(p_c, fx[o], fy[o])  # (M, 2, 6) pixels per pose tangent unit
            S = sandwich2(J_pose, cov_v[o])
        S[:, 0, 0] += s.pixel_sigma_px**2
        S[:, 1, 1] += s.pixel_sigma_px**2
        return inv2(S), J_pose

    def residuals(X, o=slice(None)):
        """Camera points and ideal-pixel residuals of the observations ``o`` at points ``X``."""
        return residuals_of(X[t[o]], o)

    def residuals_of(X_obs, o):
        """:func:`residuals` at ``X_obs`` (one point per observation of ``o``)."""
        return _project(R_cw[o], X_obs - centres[o], fx[o], fy[o], cx[o], cy[o], ideal[o])

    # Only the tracks that can still change are computed: a Gauss-Newton step rejected once
    # would be rejected again (the whitening is fixed within a round), a track that stopped
    # moving has converged, and after an outlier round only the tracks that lost an
    # observation are solved again (the others' inliers and estimate are unchanged).
    active = status == TrackStatus.VALID
    solve = active.copy()
    S_inv = np.zeros((m, 2, 2))
    # camera points and residuals of every observation at the current points, kept up to date
    # as the points move (residuals are row-wise: what recomputing them would give)
    pc_all, r_all = residuals(X)
    o = np.nonzero(solve[t])[0]  # observations of the tracks solved in this round
    S_inv[o] = obs_info(pc_all[o], o)[0]
    for round_ in range(s.outlier_rounds + 1):
        # --- Gauss-Newton on the whitened reprojection error (the whitening is fixed within
        # a round: it depends on the point only through the pose term, slowly)
        moving = solve.copy()
        for _ in range(_GN_ITERATIONS):
            rows = np.nonzero(moving)[0]
            if not len(rows):
                break
            o = np.nonzero(moving[t])[0]
            tc = (np.cumsum(moving) - 1)[t[o]]  # compact track index of each observation
            n = len(rows)
            p_c, r = pc_all[o], r_all[o]
            S_o, R_o, c_o, fx_o, fy_o = S_inv[o], R_cw[o], centres[o], fx[o], fy[o]
            use = inlier[o] & (p_c[:, 2] > 0)
            H_o, g_o, _ = normal_terms(point_jacobian(p_c, fx_o, fy_o, R_o), S_o, finite(r))
            wts = use.astype(float)
            H = sum_by(tc, wts[:, None, None] * H_o, n)
            g = sum_by(tc, wts[:, None] * g_o, n)
            step, solvable = solve3(H, -g)
            e0 = quad2(r, S_o)
            cost0 = np.bincount(tc, weights=np.where(use & np.isfinite(e0), e0, 0.0), minlength=n)
            step = finite(step)
            X_rows = X[rows]
            X_try = np.where(solvable[:, None], X_rows + step, X_rows)
            p_new, r_new = _project(R_o, X_try[tc] - c_o, fx_o, fy_o, cx[o], cy[o], ideal[o])
            e1 = quad2(r_new, S_o)
            use1 = use & (p_new[:, 2] > 0) & np.isfinite(e1)
            cost1 = np.bincount(tc, weights=np.where(use1, e1, 0.0), minlength=n)
            better = solvable & (cost1 <= cost0) & np.all(np.isfinite(X_try), axis=1)
            X[rows[better]] = X_try[better]
            X_rows = np.where(better[:, None], X_try, X_rows)
            moved = o[better[tc]]
            pc_all[moved], r_all[moved] = p_new[better[tc]], r_new[better[tc]]
            # converged: the track moved by at most 1e-7 of its distance to the cameras
            dist2 = np.bincount(tc, weights=np.sum((X_rows[tc] - c_o) ** 2, 1), minlength=n)
            scale = np.maximum(np.sqrt(dist2 / np.maximum(n_obs[rows], 1)), 1e-9)
            moving[rows] = better & (np.linalg.norm(step, axis=1) > 1e-7 * scale)
        if round_ == s.outlier_rounds:
            break
        # --- drop the worst outlier of each track that has one
        o = np.nonzero(solve[t])[0]
        p_c, r = pc_all[o], r_all[o]
        S_inv[o] = obs_info(p_c, o)[0]
        e = quad2(finite(r, nan=1e6), S_inv[o])
        e = np.where(p_c[:, 2] > 0, e, np.inf)
        bad = inlier[o] & (e > s.max_residual_sigmas**2)
        if not bad.any():
            break
        worst = np.full(n_tracks, -1.0)
        np.maximum.at(worst, t[o][bad], e[bad])
        drop = o[bad & (e == worst[t[o]])]
        inlier[drop] = False
        n_in = np.bincount(t, weights=inlier.astype(float), minlength=n_tracks)
        mark(active & (n_in < 2), TrackStatus.REPROJECTION)
        active = status == TrackStatus.VALID
        solve = np.zeros(n_tracks, bool)
        solve[t[drop]] = True
        solve &= active

    # --- final residuals, gate, covariance, per-observation depth and sigma
    p_c, r = pc_all, r_all
    S_inv, J_pose = obs_info(p_c)
    e = quad2(finite(r, nan=1e6), S_inv)
    behind = p_c[:, 2] <= 0
    inlier &= active[t] & (behind | (e <= s.max_residual_sigmas**2))
    n_in = np.bincount(t, weights=inlier.astype(float), minlength=n_tracks).astype(np.int64)
    mark(n_in < 2, TrackStatus.REPROJECTION)

    H_o, _, JtS = normal_terms(point_jacobian(p_c, fx, fy, R_cw), S_inv)
    H = sum_by(t, inlier[:, None, None] * H_o, n_tracks)
    cov_w = inv3(H)[0]

    # largest angle between inlier rays (the pair with the extreme directions)
    mean_ray = sum_by(t, np.where(inlier[:, None], rays_w, 0.0), n_tracks)
    mean_ray /= np.maximum(np.linalg.norm(mean_ray, axis=1, keepdims=True), 1e-300)
    ang = np.degrees(np.arccos(np.clip(np.sum(rays_w * mean_ray[t], 1), -1.0, 1.0)))
    spread = np.zeros(n_tracks)
    np.maximum.at(spread, t, np.where(inlier, ang, 0.0))
    max_angle = 2.0 * spread  # within a factor of 2 of the largest pairwise angle
    mark(~np.all(np.isfinite(cov_w), axis=(1, 2)) | (max_angle < _MIN_ANGLE_DEG), TrackStatus.LOW_PARALLAX)

    depth = p_c[:, 2]
    a = R_cw[:, 2, :]  # dz/dX
    Ca = np.einsum("nij,nj->ni", np.nan_to_num(cov_w)[t], a)  # H^-1 a (H^-1 symmetric)
    # with pose uncertainty, the cross term: the point was estimated from this view's pose
    var = depth_variance(a, Ca, p_c, cov_v, JtS, J_pose, inlier)
    sigma = np.sqrt(np.maximum(var, 0.0))

    front = sum_by(t, (inlier & ~(depth > 0)).astype(float), n_tracks) == 0
    mark(~front, TrackStatus.BEHIND_CAMERA)
    in_range = (depth >= s.min_depth_m) & (depth <= s.max_depth_m)
    mark(sum_by(t, (inlier & ~in_range).astype(float), n_tracks) > 0, TrackStatus.DEPTH_RANGE)
    rel = np.where(inlier, sigma / np.where(depth > 0, depth, np.nan), 0.0)
    worst_rel = np.zeros(n_tracks)
    np.maximum.at(worst_rel, t, np.nan_to_num(rel, nan=np.inf))
    worst_rel[n_in < 2] = np.inf
    mark(~(worst_rel <= s.max_relative_sigma), TrackStatus.UNCERTAIN)

    undefined = np.isin(status, (TrackStatus.TOO_FEW_VIEWS, TrackStatus.LOW_PARALLAX))
    X = np.where(undefined[:, None], np.nan, X)
    cov_w = np.where(undefined[:, None, None], np.nan, cov_w)
    return MultiviewPoints(track_ids, X, cov_w, status, n_in, max_angle, t, inlier,
                           np.linalg.norm(r, axis=1), depth, sigma, worst_rel)


def depth_in_view(points_w, covariance_w, T_w_c, pose_covariance=None) -> tuple[np.ndarray, np.ndarray]:
    """Depth and its 1-sigma of world points in a view whose pose is independent of them.

    Use it for a view that did not take part in estimating the points (a non-keyframe);
    for the observing views use :attr:`MultiviewPoints.sigma_depth`, which keeps the
    correlation.

    Args:
        points_w: (N, 3) metres.
        covariance_w: (N, 3, 3) square metres.
        T_w_c: (4, 4) camera-to-world pose of the view, metres.
        pose_covariance: (6, 6) covariance of that pose (``T_w_c * Exp(xi)``) or None.

    Returns:
        depth: (N,) metres (camera z); sigma: (N,) metres.
    """
    P = check_array("points_w", points_w, (None, 3))
    C = check_array("covariance_w", covariance_w, (len(P), 3, 3))
    T = check_array("T_w_c", T_w_c, (4, 4), finite=True)
    R_cw = T[:3, :3].T
    p_c = (P - T[:3, 3]) @ R_cw.T
    a = np.broadcast_to(R_cw[2], P.shape)
    var = np.einsum("ni,nij,nj->n", a, C, a)
    if pose_covariance is not None:
        S = check_array("pose_covariance", pose_covariance, (6, 6), finite=True)
        b = pose_jacobian(p_c)[:, 2, :]
        var = var + np.einsum("ni,ij,nj->n", b, S, b)
    return p_c[:, 2], np.sqrt(np.maximum(var, 0.0))
