"""The streaming :class:`Rescaler`: this frame's fit, the fallback order and the temporal filter."""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from vio_core.errors import InputError, SettingsError
from vio_core.settings import Presets, require_positive

from .affine import AffineFit, RansacSettings
from .depthmap import depth_sigma_map, metric_depth, predicted_relative_error
from .fit import fit_affine, fit_scale_only
from .temporal import (
    AffineKalmanFilter,
    KalmanEstimate,
    KalmanSettings,
    anchors_from_map,
    anchors_from_points,
    carry_fit,
    inflate_covariance,
)


class FitSource(str, enum.Enum):
    """Which stage of the :class:`Rescaler`'s fallback order produced the fit used."""

    FRAME = "frame"  # this frame's full fit (filtered when the temporal filter is on)
    SCALE_ONLY = "scale_only"  # alpha fitted now, beta from the previous good frame
    PREVIOUS_FIT = "previous_fit"  # the last fit that gave depth, reused
    NONE = "none"  # no metric depth for this frame


@dataclass(frozen=True)
class RescalerSettings:
    """Settings of the streaming :class:`Rescaler`.

    Attributes:
        ransac: :class:`RansacSettings` of every fit.
        fallback: when False, a failed fit gives ``NONE`` directly (the paper's behaviour).
        max_fallback_age: frames since the last ``OK`` frame after which neither fallback
            is used (the previous beta / fit is considered stale).
        temporal: :class:`vio_depth.rescale.temporal.KalmanSettings` of the (alpha, beta) filter
            (on by default), or None to use each frame's fit as is.
        max_fallback_error: a fallback frame gets depth only while its predicted relative
            depth error (:func:`~vio_depth.rescale.depthmap.predicted_relative_error`: the
            median over the map of ``sigma_D / D`` from the fallback fit's covariance, which
            grows with age by the random-walk model of ``temporal``, or of the default
            :class:`KalmanSettings` without a filter) is at most this. 0.10: on the samples
            and 7-Scenes (SIMULATED disparity) the fallback frames it admits measured AbsRel
            <= 0.10; beyond it errors grow to 0.2-0.3 (docs/safety.md).
        max_fit_error: the same bound for this frame's own fit: a fit whose predicted
            relative depth error (from its covariance: few points, narrow spread, a poor
            line) exceeds it does not give the frame status ``ok``; the fallbacks are tried
            instead, and without one the frame has no depth (status ``uncertain_fit``).
            The covariance sees the points' scatter, not a bias they share (e.g. poses
            inconsistent with the images): docs/benchmarks.md, "Landmarks".
    """

    ransac: RansacSettings = RansacSettings()
    fallback: bool = True
    max_fallback_age: int = 10
    temporal: KalmanSettings | None = KalmanSettings()
    max_fallback_error: float = 0.10
    max_fit_error: float = 0.10

    def __post_init__(self):
        if self.max_fallback_age < 1:
            raise SettingsError(f"RescalerSettings.max_fallback_age must be >= 1, got {self.max_fallback_age!r}")
        require_positive(self, "max_fallback_error", "max_fit_error", finite=False)  # relative errors


#: Named rescaler presets (``[rescaler] preset = ...`` in a config file).
RESCALER_PRESETS: Presets = Presets("rescaler preset", {
    "streaming": RescalerSettings(),
    "per_frame": RescalerSettings(temporal=None),
    "paper": RescalerSettings(fallback=False, temporal=None),
}, default="streaming", descriptions={
    "streaming": "fallbacks + Kalman filter on the scale (the default for sequences)",
    "per_frame": "fallbacks, no filter",
    "paper": "each frame alone: no fallback, no filter (the paper's behaviour)",
})


@dataclass(frozen=True)
class RescaleResult:
    """What the :class:`Rescaler` decided for one frame.

    Attributes:
        source: :class:`FitSource`, the fallback stage that produced ``fit``.
        fit: the :class:`AffineFit` to use, or None when ``source`` is NONE.
            For ``FRAME`` with the temporal filter on, the filtered (alpha, beta, covariance)
            with the raw fit's diagnostics.
        raw: this frame's full fit (:func:`fit_affine`).
        scale_only: the scale-only fallback fit when one was attempted, else None.
        filtered: the filter's output for this frame when the filter is on, else None.
        age: frames between this frame and the one whose fit is used (0 = this frame).
        reason: why this stage was chosen (joined reasons of the failed stages).
        predicted_error: the predicted relative depth error of the fit used or refused:
            this frame's own (``RescalerSettings.max_fit_error``) or a fallback's
            (``max_fallback_error``); None when there was no fit to judge.
    """

    source: FitSource
    fit: AffineFit | None
    raw: AffineFit
    scale_only: AffineFit | None = None
    filtered: KalmanEstimate | None = None
    age: int = 0
    reason: str = ""
    predicted_error: float | None = None

    @property
    def has_depth(self) -> bool:
        return self.fit is not None

    @property
    def n_inliers(self) -> int:
        """Inliers of the fit used (of the raw fit when there is none)."""
        return (self.fit if self.fit is not None else self.raw).n_inliers

    def metric_depth(self, disparity, max_depth: float | None = None) -> np.ndarray | None:
        """(H, W) float32 metres (NaN invalid) from :func:`metric_depth`, or None without depth."""
        return None if self.fit is None else metric_depth(disparity, self.fit, max_depth)

    def depth_sigma(self, disparity, max_depth: float | None = None) -> np.ndarray | None:
        """(H, W) float32 metres from :func:`depth_sigma_map`, or None without depth."""
        return None if self.fit is None else depth_sigma_map(disparity, self.fit, max_depth)


class Rescaler:
    """Per-frame rescaling with state across frames: fallbacks and temporal filtering.

    Fallback order for a frame whose full fit (:func:`fit_affine`) is not OK (only when
    ``settings.fallback`` is on and the last OK frame is at most ``max_fallback_age`` frames
    old):

    1. ``SCALE_ONLY``: :func:`fit_scale_only` with beta (and its variance) of the fit used at
       the last ``OK`` frame; used when it is OK.
    2. ``PREVIOUS_FIT``: the last fit that gave depth (``OK`` or ``SCALE_ONLY``) carried to
       this frame (:func:`~vio_depth.rescale.temporal.carry_fit`): expressed as metric
       disparities at its frame's anchor disparities, its covariance grown by the
       random-walk process model for every frame of age, and mapped back through this
       frame's anchors, so that it follows the network's renormalisation of this frame.
       Without a disparity map for either frame the fit is reused unchanged (covariance
       grown the same way).
    3. ``NONE``: no metric depth for this frame (``RescaleResult.fit is None``).

    A fallback (1 or 2) is used only while its predicted relative depth error is at most
    ``max_fallback_error``; otherwise the frame has no depth and the reason says why.

    With ``settings.temporal`` set, every OK full fit is a measurement of an
    :class:`~vio_depth.rescale.temporal.AffineKalmanFilter` (anchored at the 25 % / 75 % quantiles of
    the disparity map, see :mod:`vio_depth.rescale.temporal`: pass ``disparity_map``); the frame
    uses the filtered estimate (or the prediction when the measurement is gated out). Fallback frames are
    not fed to the filter (a scale-only fit reuses the last beta), but each frame is one
    prediction step. Call :meth:`reset` on a known scene change.

    Both fallbacks assume that the network normalised this frame like the last good one up
    to an increasing affine map that the anchors follow (beta, or the scene's metric
    disparity at the anchors, carried over). That holds for consecutive video frames, not
    across cuts.
    """

    def __init__(self, settings: RescalerSettings = RescalerSettings()):
        self.settings = settings
        self._filter = None
        if settings.temporal is not None:
            self._filter = AffineKalmanFilter(settings.temporal)
        self._process = settings.temporal if settings.temporal is not None else KalmanSettings()
        self.reset()

    def reset(self) -> None:
        """Forget all history (previous fits and the filter state)."""
        self._frame = -1
        self._last_ok_frame: int | None = None
        self._last_ok_fit: AffineFit | None = None
        self._last_used_frame: int | None = None
        self._last_used_fit: AffineFit | None = None
        self._last_used_anchors: tuple[float, float] | None = None
        self._last_used_map_anchors = False  # the anchors came from a disparity map (not the points)
        if self._filter is not None:
            self._filter.reset()

    def _anchors(self, d: np.ndarray, inliers: np.ndarray, disparity_map) -> tuple[float, float] | None:
        """This frame's anchor disparities (of the map when given, else of the inliers), or None."""
        try:
            if disparity_map is not None:
                return anchors_from_map(disparity_map, self._process)
            return anchors_from_points(d, inliers, self._process)
        except InputError:  # e.g. a constant disparity map
            return None

    def _use(self, fit: AffineFit, anchors, disparity_map) -> None:
        self._last_used_frame = self._frame
        self._last_used_fit = fit
        self._last_used_anchors = anchors
        self._last_used_map_anchors = disparity_map is not None

    def skip(self, reason: str) -> RescaleResult:
        """Count a frame that must get no depth at all (e.g. an unusable disparity map): the
        frame clock and the filter advance, no fit is made and nothing is carried over."""
        self._frame += 1
        estimate = self._filter.step(None, None) if self._filter is not None else None
        raw = fit_affine(np.zeros(0), np.zeros(0), settings=self.settings.ransac)
        return RescaleResult(FitSource.NONE, None, raw, filtered=estimate, reason=reason)

    def update(self, d, depth, sigma_depth=None, weights=None, disparity_map=None) -> RescaleResult:
        """Rescale one frame (call once per frame, in order, even with no points).

        Args:
            d: (N,) affine-invariant disparity at the points (N may be 0).
            depth: (N,) metres.
            sigma_depth: (N,) metres or None.
            weights: (N,) extra weights > 0 or None.
            disparity_map: (H, W) this frame's disparity map, or None. Used for the anchors
                of the temporal filter and of the fallbacks
                (:func:`~vio_depth.rescale.temporal.anchors_from_map`; without it they come
                from the inliers' ``d``, noisier) and for the fallbacks' predicted error.

        Returns:
            :class:`RescaleResult`.
        """
        s = self.settings
        self._frame += 1
        raw = fit_affine(d, depth, sigma_depth, weights, s.ransac)
        d = np.asarray(d, dtype=np.float64)
        estimate = anchors = None
        if raw.ok:
            anchors = self._anchors(d, raw.inliers, disparity_map)
        if self._filter is not None:
            estimate = self._filter.step(raw if anchors is not None else None, anchors)

        reasons = [f"fit {raw.status.value}: {raw.reason}"]
        own_error = None
        if raw.ok:
            used = raw
            reason = raw.reason
            if estimate is not None and anchors is not None:
                used = replace(raw, alpha=estimate.alpha, beta=estimate.beta, covariance=estimate.covariance)
                reason = f"{raw.reason}; filter: {estimate.reason}"
            error = self._predicted_error(used, disparity_map, anchors)
            if error <= s.max_fit_error:
                self._last_ok_frame = self._frame
                self._last_ok_fit = used
                self._use(used, anchors, disparity_map)
                return RescaleResult(FitSource.FRAME, used, raw, filtered=estimate, reason=reason,
                                     predicted_error=error)
            own_error = error
            reasons = [f"fit uncertain: predicted relative depth error {error:.3g} > max_fit_error "
                       f"{s.max_fit_error:g}"]
        age_ok = None if self._last_ok_frame is None else self._frame - self._last_ok_frame
        if not s.fallback:
            reasons.append("fallbacks disabled")
        elif age_ok is None:
            reasons.append("no previous good frame to fall back on")
        elif age_ok > s.max_fallback_age:
            reasons.append(f"last good frame is {age_ok} frames old (> max_fallback_age {s.max_fallback_age})")
        else:
            prev = self._last_ok_fit
            beta_var = float(prev.covariance[1, 1]) if np.isfinite(prev.covariance[1, 1]) else 0.0
            scale = fit_scale_only(d, depth, prev.beta, beta_var, sigma_depth, weights, s.ransac)
            if scale.ok:
                anchors = self._anchors(d, scale.inliers, disparity_map)
                error = self._predicted_error(scale, disparity_map, anchors)
                reasons.append(f"scale-only fit with beta of frame {self._last_ok_frame}: {scale.reason}")
                if error <= s.max_fallback_error:
                    self._use(scale, anchors, disparity_map)
                    return RescaleResult(FitSource.SCALE_ONLY, scale, raw, scale_only=scale, filtered=estimate,
                                         reason="; ".join(reasons), predicted_error=error)
                return self._refused(raw, scale, estimate, 0, error, reasons)
            reasons.append(f"scale-only {scale.status.value}: {scale.reason}")
            age = self._frame - self._last_used_frame
            used, how = self._carried(age, disparity_map)
            reasons.append(f"previous fit of frame {self._last_used_frame} ({age} frame(s) old) {how}")
            error = self._predicted_error(used, disparity_map, self._last_used_anchors)
            if error <= s.max_fallback_error:
                return RescaleResult(FitSource.PREVIOUS_FIT, used, raw, scale_only=scale, filtered=estimate,
                                     age=age, reason="; ".join(reasons), predicted_error=error)
            return self._refused(raw, scale, estimate, age, error, reasons)
        return RescaleResult(FitSource.NONE, None, raw, filtered=estimate, reason="; ".join(reasons),
                             predicted_error=own_error)

    def _carried(self, age: int, disparity_map) -> tuple[AffineFit, str]:
        """The last used fit for this frame, and how it was obtained (for the reason)."""
        used = self._last_used_fit
        then = self._last_used_anchors
        now = self._anchors(np.zeros(0), np.zeros(0, bool), disparity_map) if disparity_map is not None else None
        if then is not None and now is not None and self._last_used_map_anchors:
            alpha, beta, cov = carry_fit(used.alpha, used.beta, used.covariance, age, then, now, self._process)
            return replace(used, alpha=alpha, beta=beta, covariance=cov), "carried to this frame's disparity"
        if then is not None:
            cov = inflate_covariance(used.alpha, used.beta, used.covariance, age, then, self._process)
            return replace(used, covariance=cov), "reused unchanged (no disparity map to carry it)"
        return used, "reused unchanged"

    def _predicted_error(self, fit: AffineFit, disparity_map, anchors) -> float:
        """Predicted relative depth error of a fallback: over the map when given, else the
        larger one at the two anchors; ``inf`` when it cannot be predicted."""
        if disparity_map is not None:
            return predicted_relative_error(disparity_map, fit)
        if anchors is None:
            return float("inf")
        return predicted_relative_error(np.asarray([anchors], dtype=np.float64), fit, max_pixels=2)

    def _refused(self, raw, scale, estimate, age, error, reasons) -> RescaleResult:
        reasons.append(f"fallback refused: predicted relative depth error {error:.3g} > max_fallback_error "
                       f"{self.settings.max_fallback_error:g}")
        return RescaleResult(FitSource.NONE, None, raw, scale_only=scale, filtered=estimate, age=age,
                             reason="; ".join(reasons), predicted_error=error)
