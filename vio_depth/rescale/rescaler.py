"""The streaming :class:`Rescaler`: this frame's fit, the fallback order and the temporal filter."""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace
from statistics import NormalDist

import numpy as np

from vio_core.errors import InputError, SettingsError
from vio_core.settings import Presets, require_positive

from .affine import AffineFit, RansacSettings
from .depthmap import depth_sigma_map, expected_relative_error, metric_depth
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
        max_fit_error: the bound on the predicted rescaling error: a frame is written only
            when the fit it would use (its own, filtered or not, or a fallback) has a
            predicted mean relative depth error against the best rescaling of this disparity
            (:func:`~vio_depth.rescale.depthmap.expected_relative_error` of the fit's
            covariance, which includes the errors the points share, e.g. their pose's) of at
            most this. A frame whose own fit exceeds it tries the fallbacks, which obey the
            same bound; without one the frame has no depth (status ``uncertain_fit``).
        predicted_error_max_depth: metres; the predicted error is the mean over the pixels
            whose fitted depth is within this (inf: every pixel with depth). 80 m, the
            range a LiDAR-evaluated drive is scored on; indoors no pixel comes near it.
        max_fallback_error: a tighter bound for the fallbacks only, or None (the default):
            ``max_fit_error``.
        max_disparity_spread: points where the disparity varies by more than this fraction
            within ``spread_radius_px`` are not fitted (a point on a depth edge reads the
            other surface's disparity: :func:`~vio_depth.rescale.disparity_spread`); None
            (the default) fits every point. Corners (``--matcher klt``) sit on edges: 0.1
            there.
        spread_radius_px: the half-size of that window, pixels.
        shared_error_confidence: the probability with which the error the points share (their
            pose's, the odometry's scale: ``AffineFit.shared_covariance``) must stay within
            ``max_fit_error``, or None (the default: only the mean is bounded). That
            error is **one draw for the whole map**: it does not average over the pixels, so
            a frame's error is that draw, not its mean -- a frame whose shared error has a
            1-sigma of 3.7 % passes a bound of 0.03 on the mean (0.8 sigma) but is off by
            more than 4.4 % one time in four. A frame (and a scale-only fallback, which
            uses this frame's points) is written only when ``z sigma_shared <= max_fit_error``
            at the map's median pixel, ``z`` the two-sided normal quantile of this
            probability (0.9: z = 1.645; docs/error_model.md section 5). Off by default: at 0.9
            it removes the street drive's wrong frames with the odometry's window in a worker,
            but refuses 62 of the room's 102 frames with ``--poses imu``, whose stated IMU
            covariance is far above its actual error (SIMULATED exact IMU).
    """

    ransac: RansacSettings = RansacSettings()
    fallback: bool = True
    max_fallback_age: int = 10
    temporal: KalmanSettings | None = KalmanSettings()
    max_fit_error: float = 0.03
    predicted_error_max_depth: float = 80.0
    max_fallback_error: float | None = None
    max_disparity_spread: float | None = None
    spread_radius_px: int = 3
    shared_error_confidence: float | None = None

    def __post_init__(self):
        if self.max_fallback_age < 1:
            raise SettingsError(f"RescalerSettings.max_fallback_age must be >= 1, got {self.max_fallback_age!r}")
        require_positive(self, "max_fit_error", finite=False)  # relative errors
        require_positive(self, "predicted_error_max_depth", finite=False)
        if self.max_disparity_spread is not None:
            require_positive(self, "max_disparity_spread", finite=False)
        if isinstance(self.spread_radius_px, bool) or not isinstance(self.spread_radius_px, int) \
                or self.spread_radius_px < 1:
            raise SettingsError(f"RescalerSettings.spread_radius_px must be an integer >= 1, got "
                                f"{self.spread_radius_px!r}")
        if self.shared_error_confidence is not None and not 0 < self.shared_error_confidence < 1:
            raise SettingsError(f"RescalerSettings.shared_error_confidence must be in (0, 1) or None, got "
                                f"{self.shared_error_confidence!r}")
        if self.max_fallback_error is not None:
            require_positive(self, "max_fallback_error", finite=False)
            if self.max_fallback_error > self.max_fit_error:
                raise SettingsError(f"RescalerSettings.max_fallback_error ({self.max_fallback_error!r}) must not "
                                    f"exceed max_fit_error ({self.max_fit_error!r}): a fallback obeys the same bound")

    @property
    def shared_error_sigmas(self) -> float:
        """``z``: sigmas of the shared error that must fit within ``max_fit_error`` (0: off)."""
        if self.shared_error_confidence is None:
            return 0.0
        return float(NormalDist().inv_cdf(0.5 + 0.5 * self.shared_error_confidence))

    @property
    def fallback_bound(self) -> float:
        """The bound on a fallback's predicted error."""
        return self.max_fit_error if self.max_fallback_error is None else self.max_fallback_error


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
        predicted_error: the predicted mean relative depth error of the fit used or refused
            against the best rescaling of this disparity (what the bound
            ``RescalerSettings.max_fit_error`` judges); None when there was no fit to judge.
        predicted_abs_rel: the same plus the disparity's own error that the fit's residuals
            show (``AffineFit.model_relative_sd``): the predicted AbsRel against ground truth.
        predicted_pose_error: the part of ``predicted_error`` from errors the points share
            (their poses'), for this frame's own fit; None without such errors.
    """

    source: FitSource
    fit: AffineFit | None
    raw: AffineFit
    scale_only: AffineFit | None = None
    filtered: KalmanEstimate | None = None
    age: int = 0
    reason: str = ""
    predicted_error: float | None = None
    predicted_abs_rel: float | None = None
    predicted_pose_error: float | None = None

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
    ``RescalerSettings.fallback_bound`` (``max_fit_error``); otherwise the frame has no depth and the
    reason says why.

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
        self._last_ok_anchors: tuple[float, float] | None = None  # the last OK frame's anchors
        self._last_ok_map_anchors = False  # ... came from a disparity map (not the points)
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

    def update(self, d, depth, sigma_depth=None, weights=None, disparity_map=None, depth_shared=None) -> RescaleResult:
        """Rescale one frame (call once per frame, in order, even with no points).

        Args:
            d: (N,) affine-invariant disparity at the points (N may be 0).
            depth: (N,) metres.
            sigma_depth: (N,) metres or None.
            weights: (N,) extra weights > 0 or None.
            disparity_map: (H, W) this frame's disparity map, or None. Used for the anchors
                of the temporal filter and of the fallbacks
                (:func:`~vio_depth.rescale.temporal.anchors_from_map`; without it they come
                from the inliers' ``d``, noisier) and for the predicted errors.
            depth_shared: (N, K) metres or None: the points' sensitivities to errors they
                share (:func:`~vio_depth.rescale.fit.fit_affine`).

        Returns:
            :class:`RescaleResult`.
        """
        s = self.settings
        self._frame += 1
        raw = fit_affine(d, depth, sigma_depth, weights, s.ransac, depth_shared=depth_shared)
        d = np.asarray(d, dtype=np.float64)
        estimate = anchors = None
        if raw.ok:
            anchors = self._anchors(d, raw.inliers, disparity_map)
        if self._filter is not None:
            estimate = self._filter.step(raw if anchors is not None else None, anchors)

        reasons = [f"fit {raw.status.value}: {raw.reason}"]
        own_error = own_abs_rel = None
        pose_error = None
        if raw.ok:
            pose_error = self._shared_error(raw, disparity_map, anchors)
            used = raw
            reason = raw.reason
            if estimate is not None and anchors is not None:
                used = replace(raw, alpha=estimate.alpha, beta=estimate.beta, covariance=estimate.covariance)
                reason = f"{raw.reason}; filter: {estimate.reason}"
            error = self._predicted_error(used, disparity_map, anchors)
            if pose_error is not None:
                # the filter averages frames, but not an error that consecutive frames share
                # (the same keyframes and poses): that part of this frame's fit stays
                error = max(error, pose_error)
            abs_rel = self._predicted_error(used, disparity_map, anchors, extra=raw.model_relative_sd)
            shared_why = self._shared_too_large(pose_error)
            if error <= s.max_fit_error and not shared_why:
                self._last_ok_frame = self._frame
                self._last_ok_fit = used
                self._last_ok_anchors, self._last_ok_map_anchors = anchors, disparity_map is not None
                self._use(used, anchors, disparity_map)
                return RescaleResult(FitSource.FRAME, used, raw, filtered=estimate, reason=reason,
                                     predicted_error=error, predicted_abs_rel=abs_rel, predicted_pose_error=pose_error)
            own_error, own_abs_rel = error, abs_rel
            if error <= s.max_fit_error:
                why = shared_why
            else:
                why = f"predicted relative depth error {error:.3g} > max_fit_error {s.max_fit_error:g}"
                if pose_error is not None and pose_error >= 0.5 * error:
                    why += f" (the points' pose uncertainty alone: {pose_error:.3g})"
            reasons = [f"fit uncertain: {why}"]
        bound = s.fallback_bound
        age_ok = None if self._last_ok_frame is None else self._frame - self._last_ok_frame
        if not s.fallback:
            reasons.append("fallbacks disabled")
        elif age_ok is None:
            reasons.append("no previous good frame to fall back on")
        elif age_ok > s.max_fallback_age:
            reasons.append(f"last good frame is {age_ok} frames old (> max_fallback_age {s.max_fallback_age})")
        else:
            beta, beta_var = self._carried_beta(age_ok, disparity_map)
            scale = fit_scale_only(d, depth, beta, beta_var, sigma_depth, weights, s.ransac,
                                   depth_shared=depth_shared)
            if scale.ok:
                anchors = self._anchors(d, scale.inliers, disparity_map)
                error = self._predicted_error(scale, disparity_map, anchors)
                abs_rel = self._predicted_error(scale, disparity_map, anchors, extra=scale.model_relative_sd)
                reasons.append(f"scale-only fit with beta carried from frame {self._last_ok_frame}: {scale.reason}")
                shared_why = self._shared_too_large(self._shared_error(scale, disparity_map, anchors))
                if shared_why:
                    reasons.append(f"scale-only fit: {shared_why}")
                if error <= bound and not shared_why:
                    self._use(scale, anchors, disparity_map)
                    return RescaleResult(FitSource.SCALE_ONLY, scale, raw, scale_only=scale, filtered=estimate,
                                         reason="; ".join(reasons), predicted_error=error, predicted_abs_rel=abs_rel,
                                         predicted_pose_error=pose_error)
                return self._refused(raw, scale, estimate, 0, error, reasons, pose_error)
            reasons.append(f"scale-only {scale.status.value}: {scale.reason}")
            age = self._frame - self._last_used_frame
            used, how = self._carried(age, disparity_map)
            reasons.append(f"previous fit of frame {self._last_used_frame} ({age} frame(s) old) {how}")
            error = self._predicted_error(used, disparity_map, self._last_used_anchors)
            abs_rel = self._predicted_error(used, disparity_map, self._last_used_anchors,
                                            extra=used.model_relative_sd)
            if error <= bound:
                return RescaleResult(FitSource.PREVIOUS_FIT, used, raw, scale_only=scale, filtered=estimate,
                                     age=age, reason="; ".join(reasons), predicted_error=error,
                                     predicted_abs_rel=abs_rel, predicted_pose_error=pose_error)
            return self._refused(raw, scale, estimate, age, error, reasons, pose_error)
        return RescaleResult(FitSource.NONE, None, raw, filtered=estimate, reason="; ".join(reasons),
                             predicted_error=own_error, predicted_abs_rel=own_abs_rel, predicted_pose_error=pose_error)

    def _carried_beta(self, age: int, disparity_map) -> tuple[float, float]:
        """``(beta, variance)`` of the last OK frame's fit carried ``age`` frames to this frame
        (:meth:`_carry`: re-expressed through this frame's anchors, its variance grown by the
        process model, as the previous-fit fallback does; the beta of another frame's
        normalisation, reused unchanged, was 12 % off on a street frame that a variance not
        grown called 0.028)."""
        prev = self._last_ok_fit
        if not np.all(np.isfinite(prev.covariance)):
            prev = replace(prev, covariance=np.zeros((2, 2)))
        carried, _ = self._carry(prev, self._last_ok_anchors, self._last_ok_map_anchors, age, disparity_map)
        return float(carried.beta), float(carried.covariance[1, 1])

    def _carried(self, age: int, disparity_map) -> tuple[AffineFit, str]:
        """The last used fit for this frame, and how it was obtained (for the reason)."""
        return self._carry(self._last_used_fit, self._last_used_anchors, self._last_used_map_anchors, age,
                           disparity_map)

    def _carry(self, fit: AffineFit, then, from_map: bool, age: int, disparity_map) -> tuple[AffineFit, str]:
        """``fit``, made ``age`` frames ago with anchors ``then`` (from a disparity map when
        ``from_map``), for this frame: carried through this frame's anchors when both come from
        disparity maps, else its covariance grown by the process model; and how (for the reason)."""
        now = self._anchors(np.zeros(0), np.zeros(0, bool), disparity_map) if disparity_map is not None else None
        if then is not None and now is not None and from_map:
            alpha, beta, cov = carry_fit(fit.alpha, fit.beta, fit.covariance, age, then, now, self._process)
            return replace(fit, alpha=alpha, beta=beta, covariance=cov), "carried to this frame's disparity"
        if then is not None:
            cov = inflate_covariance(fit.alpha, fit.beta, fit.covariance, age, then, self._process)
            return replace(fit, covariance=cov), "reused unchanged (no disparity map to carry it)"
        return fit, "reused unchanged"

    def _shared_error(self, fit: AffineFit, disparity_map, anchors) -> float | None:
        """The predicted mean error of ``fit`` from the errors its points share, or None without any."""
        shared = fit.shared_covariance
        if not (np.all(np.isfinite(shared)) and np.any(shared)):
            return None
        return self._predicted_error(fit, disparity_map, anchors, covariance=shared)

    def _shared_too_large(self, shared_error: float | None) -> str:
        """Why the shared error's quantile (:attr:`RescalerSettings.shared_error_confidence`) exceeds
        ``max_fit_error``, or "" (within it, or no such error, or the check off)."""
        s = self.settings
        z = s.shared_error_sigmas
        if shared_error is None or z == 0:
            return ""
        sigma = shared_error / np.sqrt(2.0 / np.pi)  # E|e| = sqrt(2/pi) sigma
        if z * sigma <= s.max_fit_error:
            return ""
        return (f"the error the points share (pose, scale: one draw for the whole map) is {sigma:.3g} (1-sigma): "
                f"{z:.2f} sigma > max_fit_error {s.max_fit_error:g} (shared_error_confidence "
                f"{s.shared_error_confidence:g})")

    def _predicted_error(self, fit: AffineFit, disparity_map, anchors, covariance=None, extra: float = 0.0) -> float:
        """Predicted mean relative depth error of ``fit`` (with ``covariance`` instead of its
        own when given; plus an error ``extra`` that no rescaling removes, when finite): over
        the map's pixels within ``predicted_error_max_depth`` when given, else at the two
        anchors; ``inf`` when it cannot be predicted."""
        cov = fit.covariance if covariance is None else covariance
        extra = float(extra) if np.isfinite(extra) else 0.0
        max_depth = self.settings.predicted_error_max_depth
        if disparity_map is not None:
            return expected_relative_error(disparity_map, fit.alpha, fit.beta, cov, extra, max_depth=max_depth)
        if anchors is None:
            return float("inf")
        return expected_relative_error(np.asarray([anchors], dtype=np.float64), fit.alpha, fit.beta, cov, extra,
                                       max_depth=max_depth, max_pixels=2)

    def _refused(self, raw, scale, estimate, age, error, reasons, pose_error=None) -> RescaleResult:
        reasons.append(f"fallback refused: predicted relative depth error {error:.3g} > "
                       f"{self.settings.fallback_bound:g}")
        return RescaleResult(FitSource.NONE, None, raw, scale_only=scale, filtered=estimate, age=age,
                             reason="; ".join(reasons), predicted_error=error, predicted_pose_error=pose_error)
