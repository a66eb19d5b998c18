"""Temporal consistency of the rescaling: a small Kalman filter across frames.

Why not filter (alpha, beta) directly. Depth Anything normalises every frame differently:
its output is ``d = s_t * q + h_t`` (``q`` true disparity, per-frame ``s_t``, ``h_t``), so
the correct ``alpha_t = 1/s_t`` and ``beta_t = -h_t/s_t`` jump whenever the network
renormalises (the paper's ablation: per-frame fitting beats fixed parameters). A filter on
(alpha, beta) must either follow every jump (no smoothing) or smooth across jumps (wrong
maps). What *is* continuous over a video is the scene.

Parameterisation. The state is the metric disparity (1/m) of the fitted line at two
*anchor* disparities of the current frame::

    x = (m_lo, m_hi),   m_lo = alpha * d_lo + beta,   m_hi = alpha * d_hi + beta

with ``(d_lo, d_hi)`` the ``anchor_quantiles`` (25 % and 75 %) of the frame's disparity map
(:func:`anchors_from_map`; of the inliers' ``d`` when no map is given,
:func:`anchors_from_points`, which is noisier). A renormalisation is an increasing affine
map of ``d``, so quantiles of ``d`` over the image keep pointing at the same physical
depths and ``x`` is invariant to it: it changes only as the scene seen by the camera
changes. An anchor may fall on the sky (``m ~ 0``), so the state is linear in ``m`` and the
random-walk noise is relative to ``max(m_i, min_reference_fraction * m_hi)``: one
unit-free setting serves rooms at 2 m and roads at 30 m. The filtered line is mapped back
to (alpha, beta) through the current frame's anchors, which re-applies this frame's
normalisation.

A measurement is one frame's OK :class:`~vio_depth.rescale.AffineFit`; its covariance is
mapped to the state with ``A = [[d_lo, 1], [d_hi, 1]]`` and a relative
``measurement_floor`` is added in quadrature (a fit's covariance assumes independent point
errors; the network's errors are spatially correlated, so consecutive fits differ by more).

Gating and resets. The innovation's squared Mahalanobis distance is compared with the
chi-square quantile of 2 degrees of freedom at ``gate_probability`` (closed form
``-2 ln(1 - p)``); a measurement beyond it is skipped and the frame uses the prediction. A
change that is gated out ``reset_after_rejections`` times in a row is taken as a scene
change and the filter restarts from the latest measurement; a single large jump is *not*
accepted on its own, since it cannot be told apart from one bad fit. The filter also
restarts when it has only predicted for more than ``max_steps_without_update`` frames, and
on :meth:`AffineKalmanFilter.reset` (a scene change the caller knows about).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, SettingsError


@dataclass(frozen=True)
class KalmanSettings:
    """Settings of :class:`AffineKalmanFilter` (one step = one frame).

    Attributes:
        process_sigma: random-walk standard deviation per frame of the metric disparity at
            each anchor, relative (0.05 = the scene's depths at the anchors may change by
            ~5 % a frame; the anchors of a car at 6 m/s filmed at 10 Hz move by 2-3 % a
            frame, with jumps of 10 % when near objects pass). Larger follows motion faster,
            smaller smooths more (docs/benchmarks.md, "Temporal filter").
        measurement_floor: relative standard deviation added in quadrature to each
            anchor's measured metric disparity: errors the fit covariance does not see
            (e.g. a pose error shared by all points of a pair). Larger smooths noisy
            point sets more but lags behind exact ones (docs/benchmarks.md).
        min_reference_fraction: relative noises of an anchor are relative to
            ``max(m_i, min_reference_fraction * m_hi)`` (an anchor on the sky has m ~ 0).
        measurement_noise_scale: factor on the fit covariance's standard deviations.
        gate_probability: a measurement is accepted when its innovation's squared Mahalanobis
            distance is at most the chi-square(2) quantile ``-2 ln(1 - gate_probability)``
            (0.999 -> 13.8).
        reset_after_rejections: this many consecutive gated-out measurements restart the
            filter from the last of them (scene change).
        max_steps_without_update: after more prediction-only frames than this, the next
            measurement restarts the filter (the state is stale).
        anchor_quantiles: quantiles of the inliers' ``d`` used as the two anchors.
    """

    process_sigma: float = 0.05
    measurement_floor: float = 0.01
    min_reference_fraction: float = 0.1
    measurement_noise_scale: float = 1.0
    gate_probability: float = 0.999
    reset_after_rejections: int = 2
    max_steps_without_update: int = 10
    anchor_quantiles: tuple[float, float] = (0.25, 0.75)

    def __post_init__(self):
        object.__setattr__(self, "anchor_quantiles", tuple(float(q) for q in self.anchor_quantiles))
        if not (self.process_sigma >= 0 and self.measurement_floor >= 0 and self.min_reference_fraction > 0):
            raise SettingsError("KalmanSettings: process_sigma and measurement_floor must be >= 0, "
                             "min_reference_fraction > 0")
        if not self.measurement_noise_scale > 0:
            raise SettingsError(f"KalmanSettings.measurement_noise_scale must be > 0, "
                             f"got {self.measurement_noise_scale!r}")
        if not 0.0 < self.gate_probability < 1.0:
            raise SettingsError(f"KalmanSettings.gate_probability must be in (0, 1), got {self.gate_probability!r}")
        if self.reset_after_rejections < 1 or self.max_steps_without_update < 0:
            raise SettingsError("KalmanSettings: reset_after_rejections must be >= 1, max_steps_without_update >= 0")
        lo, hi = self.anchor_quantiles if len(self.anchor_quantiles) == 2 else (1.0, 0.0)
        if not 0.0 <= lo < hi <= 1.0:
            raise SettingsError(f"KalmanSettings.anchor_quantiles must be (lo, hi) with 0 <= lo < hi <= 1, "
                             f"got {self.anchor_quantiles!r}")

    @property
    def gate_threshold(self) -> float:
        """Chi-square(2) quantile at ``gate_probability``: ``-2 ln(1 - p)``."""
        return -2.0 * math.log1p(-self.gate_probability)


@dataclass(frozen=True)
class KalmanEstimate:
    """The filter's output for one frame.

    Attributes:
        alpha: filtered scale (> 0) for this frame's disparity.
        beta: filtered shift, 1/m.
        covariance: (2, 2) covariance of (alpha, beta) (first order from the state's).
        accepted: this frame's measurement was used (False: gated out or none given).
        reset: the filter (re)started from this frame's measurement.
        mahalanobis2: squared Mahalanobis distance of the innovation (NaN without one).
        reason: what happened, in words.
    """

    alpha: float
    beta: float
    covariance: np.ndarray = field(repr=False)
    accepted: bool
    reset: bool
    mahalanobis2: float
    reason: str


def anchors_from_map(disparity_map, settings: KalmanSettings = KalmanSettings(),
                     max_pixels: int = 40_000) -> tuple[float, float]:
    """The two anchor disparities of a frame: ``settings.anchor_quantiles`` of its map.

    Args:
        disparity_map: (H, W) affine-invariant disparity (non-finite pixels ignored).
        settings: :class:`KalmanSettings` (``anchor_quantiles``).
        max_pixels: the map is subsampled on a regular grid to at most about this many pixels.

    Raises:
        InputError: fewer than two distinct finite disparities.
    """
    disp = check_image("disparity_map", disparity_map)
    step = max(1, math.ceil(math.sqrt(disp.size / max_pixels)))
    values = disp[::step, ::step].ravel()
    values = values[np.isfinite(values)]
    lo, hi = np.quantile(values, settings.anchor_quantiles) if len(values) else (math.nan, math.nan)
    if not hi > lo:
        raise InputError("anchors_from_map: the disparity map has fewer than two distinct finite values")
    return float(lo), float(hi)


def anchors_from_points(d, inliers, settings: KalmanSettings = KalmanSettings()) -> tuple[float, float]:
    """Anchor disparities from the points: ``settings.anchor_quantiles`` of ``d[inliers]``.

    Noisier than :func:`anchors_from_map` (a few hundred points instead of the image).

    Args:
        d: (N,) affine-invariant disparity at the points.
        inliers: (N,) bool, the fit's inliers.

    Raises:
        InputError: fewer than two distinct inlier disparities.
    """
    d = check_array("d", d, (None,))
    inl = check_array("inliers", inliers, (len(d),), dtype="bool")
    lo, hi = np.quantile(d[inl], settings.anchor_quantiles) if inl.any() else (math.nan, math.nan)
    if not hi > lo:
        raise InputError("anchors_from_points: need at least two distinct inlier disparities")
    return float(lo), float(hi)


def _design(anchors: tuple[float, float]) -> np.ndarray:
    """``A`` with ``(m_lo, m_hi) = A @ (alpha, beta)``."""
    return np.array([[anchors[0], 1.0], [anchors[1], 1.0]])


def _reference(x: np.ndarray, settings: KalmanSettings) -> np.ndarray:
    """(2,) scales of the relative noises: ``max(m_i, min_reference_fraction * m_hi)``
    (``m_hi > 0`` for every accepted state; ``m_lo`` may be ~0 or slightly negative on sky)."""
    return np.maximum(x, settings.min_reference_fraction * x[1])


def _to_params(x: np.ndarray, P: np.ndarray, anchors: tuple[float, float]) -> tuple[float, float, np.ndarray]:
    """(alpha, beta, covariance) of the line through ``x`` at ``anchors``."""
    lo, hi = anchors
    alpha = (x[1] - x[0]) / (hi - lo)
    beta = x[0] - alpha * lo
    G = np.array([[-1.0, 1.0], [hi, -lo]]) / (hi - lo)  # A^-1
    return float(alpha), float(beta), G @ P @ G.T


def inflate_covariance(alpha: float, beta: float, covariance, steps: int, anchors: tuple[float, float],
                       settings: KalmanSettings) -> np.ndarray:
    """Covariance of (alpha, beta) after ``steps`` frames of the random-walk process model.

    Args:
        alpha, beta: the estimate.
        covariance: (2, 2) covariance of (alpha, beta).
        steps: frames elapsed (>= 0).
        anchors: (d_lo, d_hi) of the estimate's frame, d_lo < d_hi.
        settings: :class:`KalmanSettings` (``process_sigma``, ``min_reference_fraction``).

    Returns:
        (2, 2) covariance.
    """
    cov = check_array("covariance", covariance, (2, 2))
    if steps <= 0:
        return cov
    A = _design(anchors)
    x = A @ np.array([alpha, beta])
    q = settings.process_sigma * _reference(x, settings)
    P = A @ cov @ A.T + int(steps) * np.diag(q * q)
    return _to_params(x, P, anchors)[2]


def carry_fit(alpha: float, beta: float, covariance, steps: int, anchors_then: tuple[float, float],
              anchors_now: tuple[float, float], settings: KalmanSettings) -> tuple[float, float, np.ndarray]:
    """An older fit carried ``steps`` frames forward and re-expressed in this frame's disparity.

    The fit is turned into the filter's state (the metric disparity at its own frame's
    anchors), its covariance grows by ``steps`` frames of the random-walk process model
    (as in :func:`inflate_covariance`), and the line through the state is mapped back
    through *this* frame's anchors. A network that renormalises its output per frame (an
    increasing affine map of ``d``) moves the anchors with it, so the carried fit follows
    the renormalisation, which reusing ``(alpha, beta)`` unchanged does not (docs/safety.md:
    on SIMULATED disparity a reused fit was 15-340 % off, a carried one 2-10 %).

    Args:
        alpha, beta, covariance: the older fit ((2, 2) covariance of alpha, beta).
        steps: frames between the two (>= 0).
        anchors_then: (d_lo, d_hi) of the older fit's frame; anchors_now: of this frame.
        settings: :class:`KalmanSettings` (``process_sigma``, ``min_reference_fraction``).

    Returns:
        ``(alpha, beta, covariance)`` for this frame's disparity.
    """
    cov = check_array("covariance", covariance, (2, 2))
    for name, a in (("anchors_then", anchors_then), ("anchors_now", anchors_now)):
        if not (len(a) == 2 and np.all(np.isfinite(a)) and a[1] > a[0]):
            raise InputError(f"carry_fit: {name} must be (d_lo, d_hi) with d_lo < d_hi, got {a!r}")
    A = _design(anchors_then)
    x = A @ np.array([alpha, beta])
    P = A @ cov @ A.T
    if steps > 0:
        q = settings.process_sigma * _reference(x, settings)
        P = P + int(steps) * np.diag(q * q)
    return _to_params(x, P, anchors_now)


class AffineKalmanFilter:
    """Kalman filter on the metric disparities at two anchors, ``(m_lo, m_hi)``.

    Use :meth:`step` once per frame with that frame's OK fit and anchors
    (:func:`anchors_from_map`), or with None when the frame has no fit. See the module
    docstring for the model.
    """

    def __init__(self, settings: KalmanSettings = KalmanSettings()):
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        """Forget the state (e.g. on a scene change known to the caller)."""
        self._x: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._anchors: tuple[float, float] | None = None
        self._rejections = 0
        self._steps_since_update = 0

    @property
    def initialized(self) -> bool:
        return self._x is not None

    def _estimate(self, accepted: bool, reset: bool, d2: float, reason: str) -> KalmanEstimate:
        alpha, beta, cov = _to_params(self._x, self._P, self._anchors)
        return KalmanEstimate(alpha, beta, cov, accepted, reset, d2, reason)

    def _start(self, z: np.ndarray, R: np.ndarray) -> None:
        self._x = z.copy()
        self._P = R.copy()
        self._rejections = 0
        self._steps_since_update = 0

    def predict(self) -> None:
        """One frame of the random walk (no-op before the first measurement)."""
        if self._x is None:
            return
        q = self.settings.process_sigma * _reference(self._x, self.settings)
        self._P = self._P + np.diag(q * q)
        self._steps_since_update += 1

    def step(self, measurement=None, anchors: tuple[float, float] | None = None) -> KalmanEstimate | None:
        """Predict one frame, then update with ``measurement`` when given.

        Args:
            measurement: an object with ``alpha`` (> 0), ``beta`` (1/m) and ``covariance``
                ((2, 2) of alpha, beta), e.g. an OK :class:`~vio_depth.rescale.AffineFit`;
                or None.
            anchors: (d_lo, d_hi), this frame's anchor disparities (required with a
                measurement; see :func:`anchors_from_map`).

        Returns:
            :class:`KalmanEstimate` for this frame (without a measurement: the prediction,
            expressed with the last anchors), or None before the first measurement.
        """
        self.predict()
        if measurement is None:
            if self._x is None:
                return None
            return self._estimate(False, False, math.nan, "prediction only (no measurement this frame)")
        if anchors is None or not anchors[1] > anchors[0]:
            raise InputError(f"AffineKalmanFilter.step: anchors must be (d_lo, d_hi) with d_lo < d_hi, got {anchors!r}")
        alpha, beta = float(measurement.alpha), float(measurement.beta)
        cov = check_array("measurement.covariance", measurement.covariance, (2, 2))
        if not (alpha > 0 and np.isfinite(beta) and np.all(np.isfinite(cov))):
            if self._x is None:
                return None
            return self._estimate(False, False, math.nan, "measurement skipped: non-finite parameters or covariance")
        s = self.settings
        A = _design(anchors)
        z = A @ np.array([alpha, beta])
        if not z[1] > 0:
            if self._x is None:
                return None
            return self._estimate(False, False, math.nan,
                                  "measurement skipped: metric disparity <= 0 at the near anchor")
        f = s.measurement_floor * _reference(z, s)
        R = (s.measurement_noise_scale**2) * (A @ cov @ A.T) + np.diag(f * f)
        self._anchors = (float(anchors[0]), float(anchors[1]))
        if self._x is None:
            self._start(z, R)
            return self._estimate(True, True, math.nan, "initialised from this frame's fit")
        if self._steps_since_update > s.max_steps_without_update + 1:
            stale = self._steps_since_update - 1
            self._start(z, R)
            return self._estimate(True, True, math.nan, f"restarted: no update for {stale} frames")
        nu = z - self._x
        S = self._P + R
        try:
            d2 = float(nu @ np.linalg.solve(S, nu))
        except np.linalg.LinAlgError:
            d2 = math.inf
        gate = s.gate_threshold
        if not d2 <= gate:
            self._rejections += 1
            if self._rejections >= s.reset_after_rejections:
                n = self._rejections
                self._start(z, R)
                return self._estimate(True, True, d2, f"restarted: {n} consecutive measurements gated out "
                                                      f"(Mahalanobis^2 {d2:.3g} > {gate:.3g}), scene change")
            # the prediction, expressed with this frame's anchors (the state is anchor-relative)
            return self._estimate(False, False, d2, f"measurement gated out (Mahalanobis^2 {d2:.3g} > {gate:.3g})")
        K = np.linalg.solve(S.T, self._P.T).T  # P S^-1
        x_new = self._x + K @ nu
        ik = np.eye(2) - K
        P_new = ik @ self._P @ ik.T + K @ R @ K.T  # Joseph form
        if not x_new[1] > max(x_new[0], 0.0):  # m_hi <= m_lo: alpha <= 0; m_hi <= 0: no depth
            self._start(z, R)
            return self._estimate(True, True, d2, "restarted: the filtered line had alpha <= 0")
        self._x, self._P = x_new, P_new
        self._rejections = 0
        self._steps_since_update = 0
        return self._estimate(True, False, d2, f"updated (Mahalanobis^2 {d2:.3g})")
