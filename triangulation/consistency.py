"""Do the images agree with a stated relative pose? A chi-square test from epipolar residuals.

Two images see the rotation and the direction of the translation between them (5 of the
6 degrees of freedom; not the baseline's length). Linearising the signed Sampson residual
``s_i`` of every match in the relative pose's right perturbation ``xi`` (as
:func:`~triangulation.triangulate.triangulate_pair`)::

    s_i(xi) ~ s_i + J_i xi                      J: (N, 6), pixels per (rad, m)

the images alone estimate the pose correction ``d = -(J^T W J)^+ J^T W s`` (Huber weights
``W``) with covariance ``C = sigma^2 (J^T W J)^+``, ``sigma`` the residuals' own scale. In
the ``r``-dimensional subspace the images see (``r = 5`` for a real baseline), the stated
covariance ``Sigma`` of the pose predicts ``d ~ N(0, Sigma_v + C_v)``, so::

    chi2 = d_v^T (k^2 Sigma_v + C_v)^-1 d_v  ~  chi-square(r)

for a consistent pose and inflation ``k``. :func:`pose_consistency` computes it and the
pair's own variance factor (the ``k^2`` that makes ``chi2 = r``);
:class:`PoseInflation` pools the factors of recent pairs into the inflation the points
stage applies to every pose covariance (never below 1: the stated uncertainty also covers
what the images cannot see, the baseline's length). docs/error_model.md.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.geometry import skews
from vio_core.errors import SettingsError
from vio_core.stats import chi2_quantile


_STEP = 1e-6  # central-difference step of the residual Jacobian (rad, and baselines for translation)
_HUBER = 1.345  # Huber threshold in residual scales (95 % efficiency)
_MIN_MATCHES = 12


@dataclass(frozen=True)
class ConsistencySettings:
    """How the points stage tests a pair's pose against its images.

    Attributes:
        max_residual_px: matches whose epipolar (Sampson) residual under the stated pose
            exceeds this are left out of the test (wrong matches); wider than the
            triangulation gate so that a pose error is seen, not clipped.
        refuse_probability: a pair whose chi2 (with the current inflation) exceeds the
            chi-square quantile of this probability is refused (``pose_inconsistent``):
            0.999 = 20.5 for 5 degrees of freedom.
        window: recent pairs pooled into the inflation.
        prior_pairs: weight of the stated uncertainty (inflation 1) in the pool, in pairs.
        max_inflation: the inflation (a standard-deviation factor) is capped here.
    """

    max_residual_px: float = 6.0
    refuse_probability: float = 0.999
    window: int = 12
    prior_pairs: float = 2.0
    max_inflation: float = 5.0

    def __post_init__(self):
        if not (math.isfinite(self.max_residual_px) and self.max_residual_px > 0):
            raise SettingsError(f"ConsistencySettings.max_residual_px must be finite and > 0, got {self.max_residual_px!r}")
        if not 0.5 < self.refuse_probability < 1.0:
            raise SettingsError("ConsistencySettings.refuse_probability must be in (0.5, 1)")
        if self.window < 1 or not (math.isfinite(self.prior_pairs) and self.prior_pairs > 0):
            raise SettingsError("ConsistencySettings: window must be >= 1 and prior_pairs finite and > 0")
        if not (math.isfinite(self.max_inflation) and self.max_inflation >= 1):
            raise SettingsError("ConsistencySettings.max_inflation must be finite and >= 1")

    def threshold(self, dof: int) -> float:
        """The chi2 above which a pair with ``dof`` visible degrees of freedom is refused."""
        return chi2_quantile(self.refuse_probability, max(int(dof), 1))


@dataclass(frozen=True)
class PoseConsistency:
    """The images' verdict on one relative pose (module docstring).

    Attributes:
        matches: matches used (residual under ``max_residual_px``).
        dof: degrees of freedom the images see (5 with a real baseline; 0: not tested).
        chi2: of the images' pose correction against ``inflation^2 * Sigma`` (the inflation
            given to :func:`pose_consistency`), plus the correction's own noise.
        variance_factor: this pair's own estimate of ``k^2`` (0 when the images show no
            disagreement beyond their noise; inf when the pose was stated exact but
            disagrees).
        rotation_deg: size of the rotation correction the images ask for.
        direction_deg: size of the change of the translation's direction they ask for.
        residual_px: robust scale of the epipolar residuals after the correction.
    """

    matches: int
    dof: int
    chi2: float
    variance_factor: float
    rotation_deg: float
    direction_deg: float
    residual_px: float
    terms: tuple = field(default=(), repr=False, compare=False)  # (d_v, S_v, C_v) for pooling

    @property
    def tested(self) -> bool:
        return self.dof > 0

    def describe(self) -> str:
        return (f"images ask for {self.rotation_deg:.2f} deg rotation and {self.direction_deg:.1f} deg translation "
                f"direction (chi2 {self.chi2:.1f}, {self.dof} dof)")

    @classmethod
    def untested(cls, matches: int = 0) -> "PoseConsistency":
        return cls(matches, 0, 0.0, 0.0, 0.0, 0.0, math.nan)


def signed_sampson(R, t, K_cur_inv, K_ref_inv, xc, xr) -> np.ndarray:
    """(..., N) signed Sampson residuals (pixels) of homogeneous ideal pixels ``xc`` (current),
    ``xr`` (reference), each (N, 3), for a batch of relative poses ``T_ref_cur``: rotations
    ``R: (..., 3, 3)``, translations ``t: (..., 3)`` metres; ``K_cur_inv``, ``K_ref_inv``: (3, 3)."""
    F = K_ref_inv.T @ skews(t) @ R @ K_cur_inv
    # as matrix products over all points (einsum was 8x slower: the pose calibration's hot loop)
    Fxc = F @ xc.T  # (..., 3, N)
    Ftxr = np.swapaxes(F, -1, -2) @ xr.T
    err = np.sum(xr.T * Fxc, axis=-2)
    grad = np.sqrt(Fxc[..., 0, :] ** 2 + Fxc[..., 1, :] ** 2 + Ftxr[..., 0, :] ** 2 + Ftxr[..., 1, :] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return err / grad


def pose_consistency(uv_cur, uv_ref, camera_cur: Camera, camera_ref: Camera, T_ref_cur, covariance,
                     settings: ConsistencySettings = ConsistencySettings(), inflation: float = 1.0) -> PoseConsistency:
    """Test the stated relative pose of a pair against its matches (module docstring).

    Args:
        uv_cur: (N, 2) raw pixels of the matches in the current image.
        uv_ref: (N, 2) raw pixels of the same matches in the reference image.
        camera_cur, camera_ref: intrinsics and distortion.
        T_ref_cur: (4, 4) current-camera-to-reference-camera transform, metres.
        covariance: (6, 6) stated covariance of ``T_ref_cur`` (rotation rad first, then
            translation m; right perturbation), or None (exact: ``Sigma = 0``).
        settings: :class:`ConsistencySettings`.
        inflation: factor on the stated standard deviations for ``chi2``.

    Returns:
        :class:`PoseConsistency` (untested, ``dof = 0``, when the baseline is zero or fewer
        than 12 matches qualify).
    """
    uv_cur = check_array("uv_cur", uv_cur, (None, 2), finite=True).astype(np.float64)
    uv_ref = check_array("uv_ref", uv_ref, (len(uv_cur), 2), finite=True).astype(np.float64)
    T = check_transform("T_ref_cur", T_ref_cur)
    cov = np.zeros((6, 6)) if covariance is None else check_array("covariance", covariance, (6, 6), finite=True)
    R, t = T[:3, :3], T[:3, 3]
    b = float(np.linalg.norm(t))
    if b < 1e-9 or len(uv_cur) < _MIN_MATCHES:
        return PoseConsistency.untested(len(uv_cur))
    K_cur_inv, K_ref_inv = np.linalg.inv(camera_cur.K), np.linalg.inv(camera_ref.K)
    xc = np.column_stack([camera_cur.undistort_points(uv_cur), np.ones(len(uv_cur))])
    xr = np.column_stack([camera_ref.undistort_points(uv_ref), np.ones(len(uv_ref))])
    s = signed_sampson(R, t, K_cur_inv, K_ref_inv, xc, xr)
    use = np.abs(s) <= settings.max_residual_px
    n = int(use.sum())
    if n < _MIN_MATCHES:
        return PoseConsistency.untested(n)
    xc, xr, s = xc[use], xr[use], s[use]
    # Jacobian in scaled coordinates: rotation rad, translation in baselines (well conditioned)
    scale = np.array([1.0, 1.0, 1.0, b, b, b])
    steps = np.concatenate([np.eye(6) * _STEP, -np.eye(6) * _STEP])  # (12, 6) scaled perturbations
    xi = steps * scale
    Rp = R @ Rotation.from_rotvec(xi[:, :3]).as_matrix()
    tp = t + xi[:, 3:] @ R.T
    sp = signed_sampson(Rp, tp, K_cur_inv, K_ref_inv, xc, xr)  # (12, n)
    J = ((sp[:6] - sp[6:]) / (2 * _STEP)).T  # (n, 6), per scaled unit
    if not np.all(np.isfinite(J)) or not np.all(np.isfinite(s)):
        return PoseConsistency.untested(n)
    # Huber IRLS for the correction and the residual scale
    w = np.ones(n)
    for _ in range(3):
        A = J.T @ (w[:, None] * J)
        lam, V = np.linalg.eigh(A)
        vis = lam > lam.max() * 1e-6
        A_pinv = (V[:, vis] / lam[vis]) @ V[:, vis].T
        d = -A_pinv @ (J.T @ (w * s))
        r = s + J @ d
        sigma = 1.4826 * float(np.median(np.abs(r))) + 1e-3
        a = np.abs(r) / (_HUBER * sigma)
        w = np.where(a <= 1, 1.0, 1.0 / np.maximum(a, 1e-12))
    dof = int(vis.sum())
    Vv = V[:, vis]
    d_v = Vv.T @ d
    C_v = sigma**2 * np.diag(1.0 / lam[vis])
    S_v = Vv.T @ (cov / np.outer(scale, scale)) @ Vv
    chi2 = float(d_v @ np.linalg.solve(inflation**2 * S_v + C_v, d_v))
    factor = _variance_factor(d_v, S_v, C_v, dof)
    d_full = d * scale
    rot = math.degrees(float(np.linalg.norm(d_full[:3])))
    u = t / b
    moved = u + R @ d[3:]  # translation direction after the correction (baseline units)
    direction = math.degrees(math.acos(np.clip(moved @ u / max(np.linalg.norm(moved), 1e-12), -1.0, 1.0)))
    return PoseConsistency(n, dof, chi2, factor, rot, direction, sigma, (d_v, S_v, C_v))


def _variance_factor(d_v, S_v, C_v, dof) -> float:
    """The ``k^2 >= 0`` with ``d_v^T (k^2 S_v + C_v)^-1 d_v = dof`` (0 when already below at
    ``k = 0``, inf when ``S_v`` is zero and the correction exceeds its own noise)."""
    def q(k2):
        return float(d_v @ np.linalg.solve(k2 * S_v + C_v, d_v))

    if q(0.0) <= dof:
        return 0.0
    if not np.any(S_v):
        return math.inf
    lo, hi = 0.0, 1.0
    while q(hi) > dof:
        hi *= 4.0
        if hi > 1e12:
            return math.inf
    for _ in range(50):  # bisection in the log domain once bracketed
        mid = math.sqrt(max(lo, hi * 1e-12) * hi) if lo > 0 else hi / 2
        if q(mid) > dof:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-3 * hi:
            break
    return hi


class PoseInflation:
    """The inflation of stated pose covariances, estimated online from recent pairs.

    The pooled variance factor ``k^2`` of the last ``settings.window`` accepted pairs solves
    (bisection; each term decreases with ``k^2``)::

        sum_i d_i^T (k^2 S_i + C_i)^-1 d_i + r0 / k^2 = sum_i r_i + r0

    -- the pairs' chi-squares, each expected to equal its degrees of freedom ``r_i`` for the
    right ``k`` -- with the stated uncertainty counted as ``prior_pairs`` pairs of factor 1
    (``r0 = prior_pairs * mean(r_i)``). Each pair's chi-square is Winsorised at the refusal
    threshold, so one gross fault moves ``k`` little while a pose source that is worse than
    stated pair after pair moves it all the way. The reported inflation is ``k``, at least 1
    (a preset is a starting point, not a promise: the images may show it too small, never
    that the poses are better than stated) and at most ``max_inflation``.
    """

    def __init__(self, settings: ConsistencySettings = ConsistencySettings()):
        self.settings = settings
        self._terms: deque[tuple] = deque(maxlen=settings.window)
        self._value = 1.0

    def reset(self) -> None:
        self._terms.clear()
        self._value = 1.0

    @property
    def value(self) -> float:
        """The current inflation ``k`` (a factor on standard deviations, >= 1)."""
        return self._value

    def update(self, consistency: PoseConsistency) -> None:
        """Pool a tested pair, refused or not (untested ones are ignored), and re-estimate."""
        if not consistency.tested or not consistency.terms:
            return
        self._terms.append(consistency.terms)
        self._value = self._estimate()

    def _estimate(self) -> float:
        s = self.settings
        dofs = np.array([len(d) for d, _, _ in self._terms], float)
        r0 = s.prior_pairs * dofs.mean()
        target = dofs.sum() + r0

        caps = [s.threshold(len(d)) for d, _, _ in self._terms]
        # the pairs grouped by their number of visible dof, so that each bisection step
        # solves one stacked system per group (the same LAPACK solves, not one call each)
        groups = []
        for m in sorted({len(d) for d, _, _ in self._terms}):
            idx = [i for i, (d, _, _) in enumerate(self._terms) if len(d) == m]
            groups.append((idx, *(np.stack([self._terms[i][k] for i in idx]) for k in range(3))))
        chi = np.empty(len(self._terms))

        def total(k2):  # each pair's chi2 Winsorised at the refusal threshold: a gross fault counts once
            for idx, d, S, C in groups:  # d: (P, m), S, C: (P, m, m)
                chi[idx] = (d[:, None, :] @ np.linalg.solve(k2 * S + C, d[:, :, None]))[:, 0, 0]
            return sum(min(c, cap) for c, cap in zip(chi.tolist(), caps)) + r0 / k2

        lo, hi = 1.0, s.max_inflation**2
        if total(lo) <= target:
            return 1.0
        if total(hi) >= target:
            return s.max_inflation
        for _ in range(40):
            mid = math.sqrt(lo * hi)
            if total(mid) > target:
                lo = mid
            else:
                hi = mid
            if hi / lo < 1.001:
                break
        return float(math.sqrt(hi))
