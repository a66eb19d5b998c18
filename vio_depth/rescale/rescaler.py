"""The streaming :class:`Rescaler`: this frame's fit, the fallback order and the temporal filter."""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from vio_core.errors import InputError, SettingsError
from vio_core.settings import Presets

from .affine import AffineFit, RansacSettings
from .depthmap import depth_sigma_map, metric_depth
from .fit import fit_affine, fit_scale_only
from .temporal import (
    AffineKalmanFilter,
    KalmanEstimate,
    KalmanSettings,
    anchors_from_map,
    anchors_from_points,
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
    """

    ransac: RansacSettings = RansacSettings()
    fallback: bool = True
    max_fallback_age: int = 10
    temporal: KalmanSettings | None = KalmanSettings()

    def __post_init__(self):
        if self.max_fallback_age < 1:
            raise SettingsError(f"RescalerSettings.max_fallback_age must be >= 1, got {self.max_fallback_age!r}")


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
    """

    source: FitSource
    fit: AffineFit | None
    raw: AffineFit
    scale_only: AffineFit | None = None
    filtered: KalmanEstimate | None = None
    age: int = 0
    reason: str = ""

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
    2. ``PREVIOUS_FIT``: the last fit that gave depth (``OK`` or ``SCALE_ONLY``), reused
       unchanged; with the temporal filter on, its covariance is inflated by the filter's
       process noise for every frame of age.
    3. ``NONE``: no metric depth for this frame (``RescaleResult.fit is None``).

    With ``settings.temporal`` set, every OK full fit is a measurement of an
    :class:`~vio_depth.rescale.temporal.AffineKalmanFilter` (anchored at the 25 % / 75 % quantiles of
    the disparity map, see :mod:`vio_depth.rescale.temporal`: pass ``disparity_map``); the frame
    uses the filtered estimate (or the prediction when the measurement is gated out). Fallback frames are
    not fed to the filter (a scale-only fit reuses the last beta), but each frame is one
    prediction step. Call :meth:`reset` on a known scene change.

    Both fallbacks assume that the network normalised this frame like the last good one
    (beta, or alpha and beta, carried over). That holds for consecutive video frames of a
    network whose normalisation follows the scene's disparity range, not across cuts.
    """

    def __init__(self, settings: RescalerSettings = RescalerSettings()):
        self.settings = settings
        self._filter = None
        if settings.temporal is not None:
            self._filter = AffineKalmanFilter(settings.temporal)
        self.reset()

    def reset(self) -> None:
        """Forget all history (previous fits and the filter state)."""
        self._frame = -1
        self._last_ok_frame: int | None = None
        self._last_ok_fit: AffineFit | None = None
        self._last_used_frame: int | None = None
        self._last_used_fit: AffineFit | None = None
        self._last_used_anchors: tuple[float, float] | None = None
        if self._filter is not None:
            self._filter.reset()

    def _anchors(self, d: np.ndarray, inliers: np.ndarray, disparity_map) -> tuple[float, float]:
        if disparity_map is not None:
            return anchors_from_map(disparity_map, self.settings.temporal)
        return anchors_from_points(d, inliers, self.settings.temporal)

    def update(self, d, depth, sigma_depth=None, weights=None, disparity_map=None) -> RescaleResult:
        """Rescale one frame (call once per frame, in order, even with no points).

        Args:
            d: (N,) affine-invariant disparity at the points (N may be 0).
            depth: (N,) metres.
            sigma_depth: (N,) metres or None.
            weights: (N,) extra weights > 0 or None.
            disparity_map: (H, W) this frame's disparity map, or None. Used only by the
                temporal filter, for its anchors (:func:`~vio_depth.rescale.temporal.anchors_from_map`);
                without it the anchors come from the inliers' ``d`` (noisier).

        Returns:
            :class:`RescaleResult`.
        """
        s = self.settings
        self._frame += 1
        raw = fit_affine(d, depth, sigma_depth, weights, s.ransac)
        d = np.asarray(d, dtype=np.float64)
        estimate = anchors = None
        if self._filter is not None:
            if raw.ok:
                try:
                    anchors = self._anchors(d, raw.inliers, disparity_map)
                except InputError:  # e.g. a constant disparity map: use this frame's fit unfiltered
                    anchors = None
            estimate = self._filter.step(raw if anchors is not None else None, anchors)

        if raw.ok:
            used = raw
            reason = raw.reason
            if estimate is not None and anchors is not None:
                used = replace(raw, alpha=estimate.alpha, beta=estimate.beta, covariance=estimate.covariance)
                reason = f"{raw.reason}; filter: {estimate.reason}"
            self._last_ok_frame = self._last_used_frame = self._frame
            self._last_ok_fit = self._last_used_fit = used
            self._last_used_anchors = anchors
            return RescaleResult(FitSource.FRAME, used, raw, filtered=estimate, reason=reason)

        reasons = [f"fit {raw.status.value}: {raw.reason}"]
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
                self._last_used_frame = self._frame
                self._last_used_fit = scale
                if self._filter is not None:
                    try:
                        self._last_used_anchors = self._anchors(d, scale.inliers, disparity_map)
                    except InputError:
                        self._last_used_anchors = None
                return RescaleResult(FitSource.SCALE_ONLY, scale, raw, scale_only=scale, filtered=estimate,
                                     reason="; ".join(reasons + [f"scale-only fit with beta of frame "
                                                                 f"{self._last_ok_frame}: {scale.reason}"]))
            reasons.append(f"scale-only {scale.status.value}: {scale.reason}")
            age = self._frame - self._last_used_frame
            used = self._last_used_fit
            if self._filter is not None and self._last_used_anchors is not None:
                cov = inflate_covariance(used.alpha, used.beta, used.covariance, age, self._last_used_anchors,
                                         s.temporal)
                used = replace(used, covariance=cov)
            reasons.append(f"reusing the fit of frame {self._last_used_frame} ({age} frame(s) old)")
            return RescaleResult(FitSource.PREVIOUS_FIT, used, raw, scale_only=scale, filtered=estimate,
                                 age=age, reason="; ".join(reasons))
        return RescaleResult(FitSource.NONE, None, raw, filtered=estimate, reason="; ".join(reasons))
