"""The gtsam solve behind :mod:`.calibration`: time offset and camera-to-body transform from
the epipolar residuals of many frame pairs.

Unknowns: ``T_b_c`` (a ``gtsam.Pose3``, the camera in the pose body's frame) and ``dt`` (a
1-vector, seconds). For a pair (``ref``, ``cur``) at frame times ``t_r``, ``t_c`` with body
poses ``B(t)`` interpolated from the sequence (:class:`~.timeline.PoseTimeline`)::

    T_ref_cur(dt, X) = X^-1 B(t_r + dt)^-1 B(t_c + dt) X          X = T_b_c

and the pair's error vector is the signed Sampson residual of each of its matches under
``T_ref_cur`` (pixels, :func:`triangulation.consistency.signed_sampson`), passed through
a pseudo-Huber transform ``e(s) = s sqrt(2 / (1 + sqrt(1 + (s/k)^2)))`` (``e^2`` is the
pseudo-Huber cost: quadratic below ``k``, linear above, smooth everywhere, so
Levenberg-Marquardt sees no kink). One ``gtsam.CustomFactor`` per pair; its Jacobians are
central differences in the tangent space (``X Exp(xi)``, rotation first, and ``dt``), all
14 perturbed residual vectors evaluated in one vectorised call. Weak priors on ``X`` and
``dt`` fix the gauge of directions the images do not see; ``gtsam.Marginals`` gives the
covariances. The rotation diversity of the pairs is what makes ``X`` observable: the lever
arm shows through ``(R_ij - I) p`` and the rotation through the conjugation of ``R_ij``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.consistency import signed_sampson
from vio_core.camera import Camera
from vio_core.checks import check_array

from .timeline import PoseTimeline

_STEP = 1e-6  # central-difference step: rad, m and s
_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class PairMatches:
    """The matches of one frame pair, for the calibration.

    Attributes:
        t_ref, t_cur: the two frames' timestamps, seconds (the pose timeline's clock).
        uv_ref, uv_cur: (N, 2) raw pixels of the same matches in the reference and the
            current image.
        camera_ref, camera_cur: their intrinsics (and distortion).
        ref, cur: the frames' indices (for messages).
    """

    t_ref: float
    t_cur: float
    uv_ref: np.ndarray
    uv_cur: np.ndarray
    camera_ref: Camera
    camera_cur: Camera
    ref: int = -1
    cur: int = -1

    def __post_init__(self):
        uv = check_array("uv_ref", self.uv_ref, (None, 2), finite=True)
        check_array("uv_cur", self.uv_cur, (len(uv), 2), finite=True)

    def __len__(self) -> int:
        return len(self.uv_ref)


@dataclass(frozen=True)
class SolveSettings:
    """Numbers of one robust solve (see :class:`~.calibration.PoseCalibrationSettings`)."""

    pixel_sigma_px: float
    huber_sigmas: float
    prior_rotation_rad: float
    prior_translation_m: float
    prior_time_offset_s: float
    max_iterations: int


@dataclass(frozen=True)
class CalibrationEstimate:
    """The solution of one solve.

    Attributes:
        time_offset_s: ``dt``. T_b_c: (4, 4) camera-to-body transform.
        covariance: (7, 7) marginal covariance of ``(rotation rad, translation m, dt s)``,
            rotation and translation in the tangent space of ``T_b_c`` (right perturbation).
        cost: the final pseudo-Huber cost (in noise units).
    """

    time_offset_s: float
    T_b_c: np.ndarray
    covariance: np.ndarray
    cost: float


def pseudo_huber(s: np.ndarray, k: float) -> np.ndarray:
    """Signed pseudo-Huber transform of residuals ``s`` (any shape) with width ``k``: ``e^2``
    is the pseudo-Huber cost ``2 k^2 (sqrt(1 + (s/k)^2) - 1)``; NaN residuals give 0."""
    s = np.nan_to_num(np.asarray(s, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return s * np.sqrt(2.0 / (1.0 + np.sqrt(1.0 + (s / k) ** 2)))


def _invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``T: (..., 4, 4)``."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _perturbations(step: float) -> np.ndarray:
    """(12, 4, 4) ``Exp(+step e_k)`` then ``Exp(-step e_k)`` for the 6 tangent axes
    (rotation first; the translation part to first order, as every gtsam retraction)."""
    xi = np.concatenate([np.eye(6), -np.eye(6)]) * step
    D = np.tile(np.eye(4), (12, 1, 1))
    D[:, :3, :3] = Rotation.from_rotvec(xi[:, :3]).as_matrix()
    D[:, :3, 3] = xi[:, 3:]
    return D


_D = _perturbations(_STEP)


class PairModel:
    """The residuals of one pair as a function of ``(dt, T_b_c)`` (vectorised over a batch)."""

    def __init__(self, pair: PairMatches, timeline: PoseTimeline):
        self.pair = pair
        self.timeline = timeline
        self.K_cur_inv = np.linalg.inv(pair.camera_cur.K)
        self.K_ref_inv = np.linalg.inv(pair.camera_ref.K)
        n = len(pair)
        self.xc = np.column_stack([pair.camera_cur.undistort_points(np.asarray(pair.uv_cur, float)), np.ones(n)])
        self.xr = np.column_stack([pair.camera_ref.undistort_points(np.asarray(pair.uv_ref, float)), np.ones(n)])

    def subset(self, keep: np.ndarray) -> "PairModel":
        out = object.__new__(PairModel)
        out.__dict__.update(self.__dict__)
        out.xc, out.xr = self.xc[keep], self.xr[keep]
        return out

    def __len__(self) -> int:
        return len(self.xc)

    def residuals(self, X: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """(K, N) signed Sampson residuals (pixels) for ``X: (K, 4, 4)`` camera-to-body
        transforms and ``dts: (K,)`` time offsets (seconds)."""
        dts = np.asarray(dts, dtype=np.float64)
        B = self.timeline.at(np.concatenate([self.pair.t_ref + dts, self.pair.t_cur + dts]))
        M = _invert(B[: len(dts)]) @ B[len(dts):]  # body cur -> body ref
        T = _invert(X) @ M @ X
        return signed_sampson(T[:, :3, :3], T[:, :3, 3], self.K_cur_inv, self.K_ref_inv, self.xc, self.xr)

    def linearised(self, X: np.ndarray, dt: float, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(e (N,), J_X (N, 6), J_dt (N, 1))``: the robust errors at ``(X, dt)`` and their
        central-difference Jacobians in ``X``'s tangent space and in ``dt``."""
        Xs = np.concatenate([X[None], X[None] @ _D, X[None], X[None]])
        dts = np.full(15, dt)
        dts[13], dts[14] = dt + _STEP, dt - _STEP
        e = pseudo_huber(self.residuals(Xs, dts), k)
        J_X = ((e[1:7] - e[7:13]) / (2 * _STEP)).T
        J_dt = ((e[13] - e[14]) / (2 * _STEP))[:, None]
        return e[0], J_X, J_dt


def robust_scale(s: np.ndarray) -> float:
    """``1.4826 * median |s|`` of the finite residuals (pixels); inf without any."""
    s = np.abs(s[np.isfinite(s)])
    return _MAD_TO_SIGMA * float(np.median(s)) if len(s) else math.inf


def grid_time_offset(models: list[PairModel], search_s: float, step_s: float, k: float) -> float:
    """The ``dt`` in ``[-search_s, search_s]`` (grid of ``step_s``) with the lowest pseudo-Huber
    cost at ``T_b_c = I``: the starting point of the solve (0 when ``search_s`` is 0)."""
    if search_s <= 0 or step_s <= 0:
        return 0.0
    grid = np.arange(-round(search_s / step_s), round(search_s / step_s) + 1) * step_s
    X = np.tile(np.eye(4), (len(grid), 1, 1))
    cost = np.zeros(len(grid))
    for m in models:
        cost += np.sum(pseudo_huber(m.residuals(X, grid), k) ** 2, axis=1)
    return float(grid[int(np.argmin(cost))])


def solve(models: list[PairModel], settings: SolveSettings, T_b_c0: np.ndarray, dt0: float) -> CalibrationEstimate:
    """One Levenberg-Marquardt solve from ``(T_b_c0, dt0)``, then the marginal covariance."""
    import gtsam  # heavy: imported where a calibration is solved
    kx, kd = gtsam.symbol("x", 0), gtsam.symbol("d", 0)
    k = settings.huber_sigmas * settings.pixel_sigma_px
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(kx, gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[[settings.prior_rotation_rad] * 3, [settings.prior_translation_m] * 3])))
    graph.add(gtsam.PriorFactorVector(kd, np.zeros(1),
                                      gtsam.noiseModel.Isotropic.Sigma(1, settings.prior_time_offset_s)))
    for m in models:
        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(len(m), settings.pixel_sigma_px), [kx, kd],
                                     _error_function(m, kx, kd, k)))
    values = gtsam.Values()
    values.insert(kx, gtsam.Pose3(T_b_c0))
    values.insert(kd, np.array([dt0]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(settings.max_iterations)
    params.setRelativeErrorTol(1e-8)
    params.setAbsoluteErrorTol(1e-10)
    params.setDiagonalDamping(True)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    marginals = gtsam.Marginals(graph, result)
    cov = np.zeros((7, 7))
    cov[:6, :6] = marginals.marginalCovariance(kx)
    cov[6, 6] = float(marginals.marginalCovariance(kd)[0, 0])
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector([kx, kd])).fullMatrix()
    cov[:6, 6] = cov[6, :6] = joint[:6, 6]
    X, dt = result.atPose3(kx).matrix(), float(result.atVector(kd)[0])
    return CalibrationEstimate(dt, X, _pair_robust(cov, models, X, dt, k, settings.pixel_sigma_px),
                               float(graph.error(result)))


#: the covariance blocks (rotation, translation, time offset) inflated separately
_BLOCKS = (slice(0, 3), slice(3, 6), slice(6, 7))


def _pair_robust(cov: np.ndarray, models: list[PairModel], X: np.ndarray, dt: float, k: float,
                 sigma: float) -> np.ndarray:
    """The marginal covariance ``cov`` (7, 7) inflated where the pairs scatter more than their
    matches' noise says.

    ``cov`` treats every match as independent; errors shared by all matches of a pair (the
    sequence's own pose noise at those two frames, interpolation) are not. The
    cluster-robust (sandwich) covariance ``C_s = C (sum_p g_p g_p^T) C`` with the pairs'
    gradients ``g_p = J_p^T e_p / sigma^2`` sees them; each block (rotation, translation,
    time offset) is scaled by ``max(1, trace(C_b^-1 C_s,b) / dim)`` (the mean ratio: with a few
    dozen pairs the largest one is noisy), never below ``cov``.
    """
    G = np.zeros((7, 7))
    for m in models:
        e, J_X, J_dt = m.linearised(X, dt, k)
        g = np.concatenate([J_X, J_dt], axis=1).T @ e / sigma**2
        G += np.outer(g, g)
    C_s = cov @ G @ cov
    scale = np.ones(7)
    for b in _BLOCKS:
        Cb = cov[b, b]
        try:
            factor = float(np.trace(np.linalg.solve(Cb, C_s[b, b]))) / Cb.shape[0]
        except np.linalg.LinAlgError:
            factor = 1.0
        scale[b] = max(1.0, factor) if np.isfinite(factor) else 1.0
    d = np.sqrt(scale)
    return cov * np.outer(d, d)


def _error_function(model: PairModel, kx: int, kd: int, k: float):
    """The ``CustomFactor`` error function of one pair (gtsam 4.3: ``f(this, values, H)``,
    ``H`` None or the list of Jacobians to fill, one per key)."""

    def error(this, values, H):
        X = values.atPose3(kx).matrix()
        dt = float(values.atVector(kd)[0])
        if H is None:
            return pseudo_huber(model.residuals(X[None], np.array([dt]))[0], k)
        e, J_X, J_dt = model.linearised(X, dt, k)
        H[0] = J_X
        H[1] = J_dt
        return e

    return error
