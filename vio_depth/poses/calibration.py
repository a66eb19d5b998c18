"""Pose-camera consistency: a constant time offset and camera-to-body transform between a
sequence's poses and its camera, estimated from the images (issue 20, item 4).

A sequence's poses are often those of another body: a motion-capture marker body, the
depth camera of a Kinect (7-Scenes), an INS. The model::

    T_w_c(t) = T_w_b(t + dt) @ T_b_c

with ``T_w_b`` the sequence's pose trajectory interpolated in time
(:class:`~.timeline.PoseTimeline`), ``dt`` a constant time offset (seconds) and ``T_b_c`` a
constant rigid transform (camera to body). Identity and 0 when the poses are exactly the
camera's.

:func:`estimate_pose_calibration` picks frame pairs spread over the frames
(:func:`calibration_pairs`), matches their images and solves for ``(dt, T_b_c)`` with gtsam
(:mod:`.calibration_solver`: the signed Sampson residuals of every match, pseudo-Huber,
Levenberg-Marquardt, marginal covariances made robust to per-pair errors), re-gating the
matches after a first solve. :func:`decide` applies the estimate only when it is
**significant** (some part differs from zero by more than ``significance_sigmas`` and by
more than a minimum effect) and **well constrained** (every 1-sigma below its limit);
otherwise :attr:`PoseCalibration.reason` names the numbers. :func:`calibrated_poses` gives
the corrected camera poses.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm

from matchers import Features, Matcher
from vio_core.errors import CorruptImageError, SettingsError

from ..frame import Frame
from .calibration_solver import (
    CalibrationEstimate,
    PairMatches,
    PairModel,
    SolveSettings,
    grid_time_offset,
    robust_scale,
    solve,
)
from .timeline import PoseTimeline


#: at most this many re-gated solves after the first
_REGATE_ROUNDS = 3


@dataclass(frozen=True)
class PoseCalibrationSettings:
    """How the pose-camera calibration is estimated and when it is applied.

    Attributes:
        anchors: frames (evenly spread over the run) that start pairs.
        pair_gaps_s: each anchor pairs with the frame nearest to each of these times later
            (seconds): enough motion for the epipolar geometry, still overlapping views.
        min_baseline_m: pairs whose poses moved less than this are left out (metres).
        min_matches: pairs with fewer matches (after the gate) are left out.
        max_matches_per_pair: the most confident matches kept per pair (bounds the time).
        min_pairs: fewer usable pairs: nothing is estimated.
        gate_px: matches whose Sampson residual exceeds this under the starting estimate
            are wrong matches (pixels).
        regate_sigmas: after the first solve the gate becomes this many residual scales
            (never below ``min_gate_px``), and the problem is solved again.
        min_gate_px: floor of that gate, pixels.
        huber_sigmas: width of the pseudo-Huber transform in residual scales.
        pixel_sigma_px: noise of a match's Sampson residual in the first solve (pixels);
            the second uses the residuals' own robust scale.
        time_offset_search_s: a grid of time offsets within +- this (seconds) picks the
            starting point (0: start at 0).
        time_offset_search_step_s: its step, seconds.
        prior_rotation_deg / prior_translation_m / prior_time_offset_s: 1-sigma of the
            weak priors at zero that fix what the images do not see.
        max_iterations: Levenberg-Marquardt iterations per solve.
        significance_sigmas: a part (time offset, rotation, translation) is significant
            when it differs from zero by more than this many of its 1-sigmas...
        min_time_offset_s / min_rotation_deg / min_translation_m: ...and by more than this
            (smaller corrections do not matter for depth; the formal 1-sigmas miss
            systematic errors: on a SIMULATED room sequence with the camera's exact poses
            the estimate was 0.01 ms, 0.02 deg and 2.4 +- 0.2 mm,
            benchmarks/bench_pose_calibration.py).
        max_time_offset_sigma_s / max_rotation_sigma_deg / max_translation_sigma_m: well
            constrained when every 1-sigma is within these (the worst axis for rotation
            and translation).
    """

    anchors: int = 30
    pair_gaps_s: tuple[float, ...] = (0.1, 0.2, 0.3)
    min_baseline_m: float = 0.005
    min_matches: int = 20
    max_matches_per_pair: int = 300
    min_pairs: int = 8
    gate_px: float = 6.0
    regate_sigmas: float = 4.0
    min_gate_px: float = 1.0
    huber_sigmas: float = 2.0
    pixel_sigma_px: float = 1.0
    time_offset_search_s: float = 0.1
    time_offset_search_step_s: float = 0.005
    prior_rotation_deg: float = 10.0
    prior_translation_m: float = 0.2
    prior_time_offset_s: float = 0.1
    max_iterations: int = 50
    significance_sigmas: float = 3.0
    min_time_offset_s: float = 0.001
    min_rotation_deg: float = 0.1
    min_translation_m: float = 0.005
    max_time_offset_sigma_s: float = 0.002
    max_rotation_sigma_deg: float = 0.2
    max_translation_sigma_m: float = 0.005

    def __post_init__(self):
        for name in ("min_baseline_m", "gate_px", "regate_sigmas", "min_gate_px", "huber_sigmas", "pixel_sigma_px",
                     "prior_rotation_deg", "prior_translation_m", "prior_time_offset_s", "significance_sigmas",
                     "max_time_offset_sigma_s", "max_rotation_sigma_deg", "max_translation_sigma_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SettingsError(f"PoseCalibrationSettings.{name} must be finite and > 0, got {v!r}")
        for name in ("time_offset_search_s", "time_offset_search_step_s", "min_time_offset_s", "min_rotation_deg",
                     "min_translation_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SettingsError(f"PoseCalibrationSettings.{name} must be finite and >= 0, got {v!r}")
        for name in ("anchors", "min_matches", "max_matches_per_pair", "min_pairs", "max_iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise SettingsError(f"PoseCalibrationSettings.{name} must be an integer >= 1, got {v!r}")
        if not self.pair_gaps_s or not all(isinstance(g, (int, float)) and math.isfinite(g) and g > 0
                                           for g in self.pair_gaps_s):
            raise SettingsError("PoseCalibrationSettings.pair_gaps_s must be positive seconds, "
                                f"got {self.pair_gaps_s!r}")
        if self.min_matches < 8:
            raise SettingsError(f"PoseCalibrationSettings.min_matches must be >= 8, got {self.min_matches}")


@dataclass(frozen=True)
class PoseCalibration:
    """The estimated pose-camera calibration and whether it is applied.

    Attributes:
        time_offset_s: ``dt`` (seconds): the camera's image at ``t`` has the body pose at
            ``t + dt``. time_offset_sigma_s: its 1-sigma.
        T_b_c: (4, 4) camera-to-body transform (identity when nothing was estimated).
        rotation_deg: angle of ``T_b_c``'s rotation. rotation_sigma_deg: 1-sigma, worst axis.
        translation_m: length of ``T_b_c``'s translation (the camera's position in the body
            frame). translation_sigma_m: 1-sigma, worst axis.
        applied: the run uses the corrected poses.
        reason: why (not) applied, with the numbers.
        estimated: a solve ran (False: skipped; then the numbers are zeros / inf).
        pairs / matches: frame pairs and matches the final solve used.
        residual_before_px / residual_after_px: median |Sampson residual| of those matches
            under the sequence's poses and under the calibrated ones (pixels).
        seconds: time the estimate took.
        covariance: (7, 7) of (rotation rad, translation m, time offset s), the rotation and
            translation in the body frame, or None when nothing was estimated.
    """

    time_offset_s: float = 0.0
    time_offset_sigma_s: float = math.inf
    T_b_c: np.ndarray = field(default_factory=lambda: np.eye(4))
    rotation_deg: float = 0.0
    rotation_sigma_deg: float = math.inf
    translation_m: float = 0.0
    translation_sigma_m: float = math.inf
    applied: bool = False
    reason: str = ""
    estimated: bool = False
    pairs: int = 0
    matches: int = 0
    residual_before_px: float = math.nan
    residual_after_px: float = math.nan
    seconds: float = 0.0
    covariance: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def skipped(cls, reason: str, **counts) -> "PoseCalibration":
        """Nothing estimated (or nothing usable), for ``reason``."""
        return cls(reason=reason, **counts)

    def summary(self) -> str:
        """One line for the printed run summary."""
        if not self.estimated:
            return f"pose calibration: not estimated ({self.reason})"
        verdict = "applied" if self.applied else "not applied"
        return (f"pose calibration {verdict}: time offset {self.time_offset_s * 1e3:.1f} +- "
                f"{self.time_offset_sigma_s * 1e3:.1f} ms, rotation {self.rotation_deg:.2f} +- "
                f"{self.rotation_sigma_deg:.2f} deg, translation {self.translation_m * 1e3:.1f} +- "
                f"{self.translation_sigma_m * 1e3:.1f} mm ({self.pairs} pairs, Sampson "
                f"{self.residual_before_px:.2f} -> {self.residual_after_px:.2f} px)"
                + ("" if self.applied else f"; {self.reason}"))

    def to_json(self) -> dict:
        """Plain dict (``metrics.json``'s ``pose_calibration``); inf / NaN become None."""
        def num(v):
            return None if not math.isfinite(v) else float(v)

        rotvec = Rotation.from_matrix(self.T_b_c[:3, :3]).as_rotvec()
        return {
            "applied": self.applied, "reason": self.reason, "estimated": self.estimated,
            "time_offset_s": num(self.time_offset_s), "time_offset_sigma_s": num(self.time_offset_sigma_s),
            "rotation_deg": num(self.rotation_deg), "rotation_sigma_deg": num(self.rotation_sigma_deg),
            "translation_m": num(self.translation_m), "translation_sigma_m": num(self.translation_sigma_m),
            "rotation_vector_deg": [float(v) for v in np.degrees(rotvec)],
            "translation_vector_m": [float(v) for v in self.T_b_c[:3, 3]],
            "T_b_c": [[float(v) for v in row] for row in self.T_b_c],
            "pairs": self.pairs, "matches": self.matches,
            "residual_before_px": num(self.residual_before_px), "residual_after_px": num(self.residual_after_px),
            "seconds": round(self.seconds, 2),
        }


def calibrated_poses(timeline: PoseTimeline, t, calibration: PoseCalibration) -> np.ndarray:
    """Camera-to-world poses ``T_w_b(t + dt) @ T_b_c`` at ``t: (K,)`` seconds, (K, 4, 4)
    (a scalar ``t`` gives (4, 4)); the sequence's own (interpolated) poses when the
    calibration is not applied."""
    if not calibration.applied:
        return timeline.at(t)
    shifted = np.asarray(t, dtype=np.float64) + calibration.time_offset_s
    return timeline.at(shifted) @ calibration.T_b_c


def calibration_pairs(timestamps, positions, settings: PoseCalibrationSettings) -> list[tuple[int, int]]:
    """Frame pairs for the calibration: ``settings.anchors`` anchors evenly spread over the
    frames, each paired with the frame nearest to each ``pair_gaps_s`` later.

    Args:
        timestamps: (N,) seconds, increasing.
        positions: (N, 3) the frames' pose positions, metres (pairs that moved less than
            ``min_baseline_m`` are left out).

    Returns:
        ``(i, j)`` index pairs into ``timestamps`` with ``i < j``, each pair once.
    """
    ts = np.asarray(timestamps, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    n = len(ts)
    if n < 2:
        return []
    anchors = np.unique(np.linspace(0, n - 1, min(settings.anchors, n)).round().astype(int))
    pairs: list[tuple[int, int]] = []
    for i in anchors:
        for gap in settings.pair_gaps_s:
            j = int(np.argmin(np.abs(ts - (ts[i] + gap))))
            if j > i and (i, j) not in pairs and np.linalg.norm(p[j] - p[i]) >= settings.min_baseline_m:
                pairs.append((int(i), j))
    return pairs


def match_pairs(frames: Mapping[int, Frame], pairs: list[tuple[int, int]], matcher: Matcher,
                max_matches: int) -> list[PairMatches]:
    """Features once per frame (:meth:`Matcher.extract`), matches per pair
    (:meth:`Matcher.match`), the ``max_matches`` most confident kept. Frames whose image is
    corrupt leave their pairs out."""
    features: dict[int, Features | None] = {}

    def feats(i: int) -> Features | None:
        if i not in features:
            try:
                features[i] = matcher.extract(frames[i].image())
            except CorruptImageError:
                features[i] = None
        return features[i]

    out = []
    for i, j in pairs:
        fa, fb = feats(i), feats(j)
        if fa is None or fb is None:
            continue
        m = matcher.match(fa, fb)
        keep = np.argsort(-np.asarray(m.confidence), kind="stable")[:max_matches]
        a, b = frames[i], frames[j]
        out.append(PairMatches(a.timestamp, b.timestamp, fa.keypoints[m.idx_a[keep]].astype(np.float64),
                               fb.keypoints[m.idx_b[keep]].astype(np.float64), a.camera, b.camera, a.index, b.index))
    return out


def estimate_pose_calibration(frames: list[Frame], matcher: Matcher,
                              settings: PoseCalibrationSettings = PoseCalibrationSettings()) -> PoseCalibration:
    """Estimate and judge the pose-camera calibration of a run's frames.

    Args:
        frames: the run's frames in time order (cheap :class:`Frame` objects; images are
            loaded only for the chosen pairs); frames without a pose are ignored.
        matcher: features and matches (e.g. ``matchers.create_matcher("sift")``).
        settings: :class:`PoseCalibrationSettings`.

    Returns:
        :class:`PoseCalibration` (``estimated`` False with a reason when too few frames,
        pairs or matches).
    """
    t0 = time.perf_counter()
    posed = [f for f in frames if f.T_w_c is not None]
    if len(posed) < 2:
        return PoseCalibration.skipped(f"{len(posed)} frames with poses")
    ts = np.array([f.timestamp for f in posed], dtype=np.float64)
    if np.any(np.diff(ts) <= 0):
        return PoseCalibration.skipped("frame timestamps do not increase")
    timeline = PoseTimeline(ts, np.array([f.T_w_c for f in posed]))
    index_pairs = calibration_pairs(ts, timeline.poses[:, :3, 3], settings)
    if len(index_pairs) < settings.min_pairs:  # decided before any image is read
        return PoseCalibration.skipped(f"{len(index_pairs)} frame pairs that moved at least "
                                       f"{settings.min_baseline_m * 1e3:g} mm (need {settings.min_pairs})",
                                       pairs=len(index_pairs))
    by_position = dict(enumerate(posed))
    pairs = match_pairs(by_position, index_pairs, matcher, settings.max_matches_per_pair)
    result = solve_pose_calibration(pairs, timeline, settings)
    return replace(result, seconds=time.perf_counter() - t0)


def solve_pose_calibration(pairs: list[PairMatches], timeline: PoseTimeline,
                           settings: PoseCalibrationSettings = PoseCalibrationSettings()) -> PoseCalibration:
    """Estimate ``(dt, T_b_c)`` from the matches of frame pairs and judge it (:func:`decide`).

    Args:
        pairs: :class:`PairMatches` (timestamps on ``timeline``'s clock).
        timeline: the sequence's poses in time.
        settings: :class:`PoseCalibrationSettings`.
    """
    t0 = time.perf_counter()
    k0 = settings.huber_sigmas * settings.pixel_sigma_px
    models = [PairModel(p, timeline) for p in pairs if len(p) >= settings.min_matches]
    if len(models) < settings.min_pairs:
        return PoseCalibration.skipped(f"{len(models)} frame pairs with >= {settings.min_matches} matches "
                                       f"(need {settings.min_pairs})", pairs=len(models))
    dt0 = grid_time_offset(models, settings.time_offset_search_s, settings.time_offset_search_step_s, k0)
    identity = np.eye(4)[None]
    models = _gate(models, identity[0], dt0, settings.gate_px, settings.min_matches)
    if len(models) < settings.min_pairs:
        return PoseCalibration.skipped(f"{len(models)} frame pairs keep >= {settings.min_matches} matches within "
                                       f"{settings.gate_px:g} px of the epipolar geometry (need {settings.min_pairs})",
                                       pairs=len(models))
    solve_settings = SolveSettings(settings.pixel_sigma_px, settings.huber_sigmas,
                                   math.radians(settings.prior_rotation_deg), settings.prior_translation_m,
                                   settings.prior_time_offset_s, settings.max_iterations)
    est = solve(models, solve_settings, np.eye(4), dt0)
    gated = models
    for _ in range(_REGATE_ROUNDS):  # re-gate around the solution and solve again, until the matches settle
        sigma = max(robust_scale(np.concatenate([m.residuals(est.T_b_c[None], np.array([est.time_offset_s]))[0]
                                                 for m in gated])), 1e-3)
        gate = max(settings.regate_sigmas * sigma, settings.min_gate_px)
        regated = _gate(models, est.T_b_c, est.time_offset_s, gate, settings.min_matches)
        if len(regated) < settings.min_pairs:
            break
        same = [len(m) for m in regated] == [len(m) for m in gated]
        gated = regated
        est = solve(gated, replace(solve_settings, pixel_sigma_px=sigma), est.T_b_c, est.time_offset_s)
        if same:
            break
    models = gated
    before = np.concatenate([m.residuals(identity, np.zeros(1))[0] for m in models])
    after = np.concatenate([m.residuals(est.T_b_c[None], np.array([est.time_offset_s]))[0] for m in models])
    result = _result(est, pairs=len(models), matches=int(sum(len(m) for m in models)),
                     residual_before_px=float(np.nanmedian(np.abs(before))),
                     residual_after_px=float(np.nanmedian(np.abs(after))), seconds=time.perf_counter() - t0)
    applied, reason = decide(result, settings)
    return replace(result, applied=applied, reason=reason)


def _gate(models: list[PairModel], X: np.ndarray, dt: float, gate_px: float, min_matches: int) -> list[PairModel]:
    """The models with only the matches within ``gate_px`` under ``(X, dt)``; pairs left with
    fewer than ``min_matches`` are dropped."""
    out = []
    for m in models:
        s = m.residuals(X[None], np.array([dt]))[0]
        keep = np.isfinite(s) & (np.abs(s) <= gate_px)
        if keep.sum() >= min_matches:
            out.append(m.subset(keep))
    return out


def _result(est: CalibrationEstimate, **counts) -> PoseCalibration:
    cov = est.covariance
    rotvec = Rotation.from_matrix(est.T_b_c[:3, :3]).as_rotvec()
    # the solver's translation lives in T_b_c's own frame (X Exp(xi)); rotate it into the body frame
    A = np.eye(7)
    A[3:6, 3:6] = est.T_b_c[:3, :3]
    cov = A @ cov @ A.T
    return PoseCalibration(
        time_offset_s=est.time_offset_s, time_offset_sigma_s=math.sqrt(max(cov[6, 6], 0.0)), T_b_c=est.T_b_c,
        rotation_deg=math.degrees(float(np.linalg.norm(rotvec))),
        rotation_sigma_deg=math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov[:3, :3])[-1]), 0.0))),
        translation_m=float(np.linalg.norm(est.T_b_c[:3, 3])),
        translation_sigma_m=math.sqrt(max(float(np.linalg.eigvalsh(cov[3:6, 3:6])[-1]), 0.0)),
        estimated=True, covariance=cov, **counts)


def _sigmas_from_zero(value: np.ndarray, cov: np.ndarray) -> float:
    """How many sigmas ``value`` (d,) lies from zero under ``cov`` (d, d): the 1-D sigma count
    with the same chi-square tail probability as ``value^T cov^-1 value`` with d degrees of
    freedom (so 3 means p = 0.27 % for a vector as for a scalar)."""
    try:
        q = float(value @ np.linalg.solve(cov, value))
    except np.linalg.LinAlgError:
        return 0.0
    tail = float(chi2.sf(q, len(value)))
    return float(norm.isf(tail / 2)) if tail > 0 else math.inf


def decide(calibration: PoseCalibration, settings: PoseCalibrationSettings) -> tuple[bool, str]:
    """``(apply, reason)`` for an estimated calibration: apply only when it is well constrained
    (every 1-sigma, the worst axis for rotation and translation, within its limit) and
    significant (some part beyond ``significance_sigmas`` from zero, the rotation vector
    and the translation by their chi-square with 3 degrees of freedom, and beyond its
    minimum effect)."""
    c, k = calibration, settings.significance_sigmas
    loose = []
    if c.time_offset_sigma_s > settings.max_time_offset_sigma_s:
        loose.append(f"time offset sigma {c.time_offset_sigma_s * 1e3:.2f} ms > "
                     f"{settings.max_time_offset_sigma_s * 1e3:g} ms")
    if c.rotation_sigma_deg > settings.max_rotation_sigma_deg:
        loose.append(f"rotation sigma {c.rotation_sigma_deg:.3f} deg > {settings.max_rotation_sigma_deg:g} deg")
    if c.translation_sigma_m > settings.max_translation_sigma_m:
        loose.append(f"translation sigma {c.translation_sigma_m * 1e3:.1f} mm > "
                     f"{settings.max_translation_sigma_m * 1e3:g} mm")
    numbers = (f"time offset {c.time_offset_s * 1e3:.2f} +- {c.time_offset_sigma_s * 1e3:.2f} ms, rotation "
               f"{c.rotation_deg:.3f} +- {c.rotation_sigma_deg:.3f} deg, translation {c.translation_m * 1e3:.1f} +- "
               f"{c.translation_sigma_m * 1e3:.1f} mm")
    if loose:
        return False, f"not well constrained ({'; '.join(loose)}): {numbers}"
    cov = c.covariance if c.covariance is not None else np.diag([math.inf] * 7)
    rotvec = Rotation.from_matrix(c.T_b_c[:3, :3]).as_rotvec()
    significant = [name for name, value, sigmas, minimum in (
        ("time offset", abs(c.time_offset_s), _sigmas_from_zero(np.array([c.time_offset_s]), cov[6:, 6:]),
         settings.min_time_offset_s),
        ("rotation", c.rotation_deg, _sigmas_from_zero(rotvec, cov[:3, :3]), settings.min_rotation_deg),
        ("translation", c.translation_m, _sigmas_from_zero(c.T_b_c[:3, 3], cov[3:6, 3:6]), settings.min_translation_m),
    ) if sigmas > k and value >= minimum]
    if not significant:
        return False, f"not significant (nothing beyond {k:g} sigma and its minimum effect): {numbers}"
    return True, f"{' and '.join(significant)} significant: {numbers}"
