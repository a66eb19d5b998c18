"""Initialisation from nothing: a static start, else a dynamic (visual-inertial) one.

Frames are offered in order (:meth:`Initializer.process`) until one of the two succeeds:

* **static**: the IMU has been still for ``init.static.min_still_s`` up to the frame
  (:func:`vio_depth.poses.static_initialisation`: roll/pitch from the mean specific force,
  gyroscope bias from the mean rate) *and* the images are still (median keypoint motion
  since the first frame offered below ``still_flow_px``; an IMU alone cannot tell rest
  from uniform motion). The frame starts the window at rest (velocity zero).
* **dynamic**: frames with at least ``min_parallax_deg`` of median keypoint motion since
  the previous candidate (rotation removed with the gyroscope, so that turning on the
  spot gives no candidates) collect as candidate keyframes; once ``min_keyframes`` of them
  span ``min_duration_s``, they are reconstructed up to scale (:mod:`.sfm`) and aligned
  with the IMU (:mod:`.alignment`), again on every new candidate while that is refused:
  a refused alignment (e.g. too little excitation yet) keeps the candidates, so that the
  start covers the first frames once the motion is rich enough; a failed reconstruction
  drops the oldest candidate; beyond ``max_duration_s`` the oldest is dropped too (VINS-Mono's
  sliding initialisation), and beyond ``max_keyframes`` the one closest in time to its
  neighbours (so that the candidates keep spanning more time).

Every frame offered before success gets a reason (:class:`InitResult`): still waiting
(how many candidates, how long), or the last refusal.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import numpy as np

from matchers import Features, Matcher
from vio_core.camera import Camera

from ..frame import ImuData
from ..landmarks import FrameMatches
from ..poses import StaticInitSettings, preintegrate, static_initialisation
from .alignment import Alignment
from .dynamic_start import DynamicAttempt, DynamicOutcome, attempt_dynamic
from .imu_factors import KeyframeState
from .matching import rotation_free_flow
from .settings import VioSettings
from .sfm import SfmKeyframe, SfmResult

#: fewer matches with the previous candidate than this restarts the candidates
_MIN_MATCHES = 20


@dataclass
class Candidate:
    """A frame offered to the initialisation: id, time, camera, features and its matches
    with earlier candidates (:class:`~vio_depth.landmarks.FrameMatches`)."""

    frame_id: int
    t: float
    camera: Camera
    features: Features
    matches: tuple[FrameMatches, ...] = ()


class InitKind(str, enum.Enum):
    """How the odometry was initialised (module docstring)."""

    STATIC = "static"
    DYNAMIC = "dynamic"


@dataclass(frozen=True)
class InitResult:
    """Outcome of offering one frame.

    Attributes:
        ok: True when the estimator can start.
        kind: :class:`InitKind` when ok, else None.
        reason: why not yet (waiting, or the last refusal); "" when ok.
        keyframes: the keyframes that start the window (oldest first), with their states.
        states: the :class:`KeyframeState` of each keyframe (the first one's sigmas are its prior).
        frames: ``(frame id, time)`` of the other frames offered since the first keyframe,
            to be posed from the keyframes after the start.
        sfm / alignment: the dynamic start's intermediate results (diagnostics), or None.
        attempt: (``process(..., defer=True)``) the dynamic attempt's conditions hold at this
            frame: the caller runs it (:meth:`Initializer.attempt_inputs`).
    """

    ok: bool
    kind: InitKind | None = None
    reason: str = ""
    keyframes: tuple[Candidate, ...] = ()
    states: tuple[KeyframeState, ...] = ()
    frames: tuple[tuple[int, float], ...] = ()
    sfm: SfmResult | None = None
    alignment: Alignment | None = None
    attempt: bool = False


@dataclass
class _Waiting:
    candidates: list[Candidate] = field(default_factory=list)
    frames: list[tuple[int, float]] = field(default_factory=list)
    last_failure: str = ""


class Initializer:
    """Static or dynamic initialisation (module docstring).

    Args:
        imu: the IMU samples (:meth:`update_samples` for streams).
        matcher: matches the offered frames' features.
        settings: :class:`~vio_depth.vio.VioSettings` (``init``, bias prior sigmas).
        params: gtsam preintegration parameters.
    """

    def __init__(self, imu: ImuData, matcher: Matcher, settings: VioSettings, params):
        self.imu = imu
        self.matcher = matcher
        self.settings = settings
        self.params = params
        self._w = _Waiting()

    def reset(self) -> None:
        self._w = _Waiting()

    def update_samples(self, imu: ImuData) -> None:
        self.imu = imu

    def candidates(self) -> tuple[Candidate, ...]:
        """The candidate keyframes waiting, oldest first."""
        return tuple(self._w.candidates)

    def offered_frames(self) -> list[tuple[int, float]]:
        """``(id, t)`` of the frames offered since the oldest candidate."""
        return list(self._w.frames)

    def candidate_times(self) -> list[float]:
        """Seconds of the candidate keyframes waiting (their IMU is read at the next alignment)."""
        return [c.t for c in self._w.candidates]

    # ------------------------------------------------------------------ helpers
    def _rotation_free_parallax(self, cur: Candidate, prev: Candidate, m) -> float:
        """Median pixel motion of the matches after removing the gyroscope's rotation."""
        s = self.settings
        pim, _ = preintegrate(self.imu, prev.t, cur.t, self.params, np.zeros(3), np.zeros(3), s.imu.max_sample_gap_s)
        if pim is None:
            return float(np.median(np.linalg.norm(cur.features.keypoints[m.idx_a] - prev.features.keypoints[m.idx_b],
                                                  axis=1)))
        R_ci = self.imu.T_c_i[:3, :3]
        R_prev_cur = R_ci @ pim.deltaRij().matrix() @ R_ci.T  # camera rotation, current -> previous
        return rotation_free_flow(cur.features.keypoints[m.idx_a], prev.features.keypoints[m.idx_b], cur.camera,
                                  prev.camera, R_prev_cur)

    def _static(self, cur: Candidate) -> InitResult | None:
        """A static start at ``cur``, or None when the IMU or the images are not still."""
        s = self.settings
        first = self._w.candidates[0] if self._w.candidates else None
        if first is None or first.frame_id == cur.frame_id:
            return None
        st: StaticInitSettings = s.init.static
        t0 = max(float(self.imu.t[0]), cur.t - s.init.lookback_s)
        window = self.imu.window(t0, cur.t)
        if len(window.t) < 10 or window.t[-1] - window.t[0] < st.min_still_s:
            return None
        still = static_initialisation(window, replace(st, start_s=0.0))
        if not still.ok or still.t_end < cur.t - st.window_s - 1e-6:
            return None
        m = self.matcher.match(cur.features, first.features)
        if len(m) < _MIN_MATCHES:
            return None
        flow = float(np.median(np.linalg.norm(cur.features.keypoints[m.idx_a] - first.features.keypoints[m.idx_b],
                                              axis=1)))
        if flow > s.init.still_flow_px:
            return None
        T = np.eye(4)
        T[:3, :3] = still.R_w_i
        G = float(np.linalg.norm(self.imu.gravity_w))
        tilt = float(np.hypot(np.nan_to_num(still.tilt_sigma_rad), s.imu.accel_bias_prior_sigma / G))
        g_sigma = float(max(np.max(np.nan_to_num(still.gyro_bias_sigma)), 2e-4))
        state = KeyframeState(cur.t, T, np.zeros(3), np.zeros(3), np.asarray(still.gyro_bias, float),
                              tilt_sigma=max(tilt, 1e-3), yaw_sigma=s.gauge_yaw_sigma_rad,
                              position_sigma=s.gauge_sigma_m, velocity_sigma=s.velocity_sigma,
                              accel_bias_sigma=s.imu.accel_bias_prior_sigma, gyro_bias_sigma=g_sigma)
        return InitResult(True, InitKind.STATIC, keyframes=(replace(cur, matches=()),), states=(state,))

    def _dynamic(self) -> InitResult:
        cands = tuple(self._w.candidates)
        return self.attempt_result(attempt_dynamic(self.attempt_inputs(), self.params), cands)

    def attempt_inputs(self, imu_span: bool = False) -> DynamicAttempt:
        """The dynamic attempt's inputs from the candidates waiting (:mod:`.dynamic_start`);
        ``imu_span``: with the IMU samples over their span only (to send them elsewhere)."""
        cands = self._w.candidates
        ids = {c.frame_id for c in cands}
        keyframes = tuple(SfmKeyframe(c.frame_id, c.camera, np.asarray(c.features.keypoints, float),
                                      tuple(m for m in c.matches if m.keyframe in ids)) for c in cands)
        imu = self.imu.window(cands[0].t, cands[-1].t) if imu_span else self.imu
        return DynamicAttempt(keyframes, np.array([c.t for c in cands]), imu, self.settings)

    def attempt_result(self, out: DynamicOutcome, candidates: tuple[Candidate, ...],
                       frames: list[tuple[int, float]] | None = None) -> InitResult:
        """The :class:`InitResult` of an attempt over ``candidates`` (:meth:`attempt_inputs` then);
        ``frames``: ``(id, t)`` of the frames offered (default: those since the first candidate)."""
        if not out.ok:
            return InitResult(False, reason=out.reason, sfm=out.sfm, alignment=out.alignment)
        ids = {c.frame_id for c in candidates}
        t0 = candidates[0].t
        frames = tuple((f, t) for f, t in (self._w.frames if frames is None else frames) if t > t0 and f not in ids)
        return InitResult(True, InitKind.DYNAMIC, keyframes=tuple(candidates), states=out.states, frames=frames,
                          sfm=out.sfm, alignment=out.alignment)

    # ------------------------------------------------------------------ per frame
    def refuse(self, reason: str, drop_oldest: bool = True, oldest: int | None = None) -> None:
        """The last start was refused (``reason``); ``drop_oldest``: forget the oldest candidate
        (with ``oldest``, a frame id: only while that is still the oldest)."""
        self._w.last_failure = reason
        if drop_oldest and self._w.candidates and oldest in (None, self._w.candidates[0].frame_id):
            self._w.candidates.pop(0)

    def process(self, frame_id: int, t: float, camera: Camera, features: Features, defer: bool = False) -> InitResult:
        """Offer the next frame (see the module docstring); ``defer``: do not run a dynamic
        attempt whose conditions hold, say so (``attempt``: the caller runs it elsewhere)."""
        s = self.settings.init
        w = self._w
        cur = Candidate(int(frame_id), float(t), camera, features)
        w.frames.append((cur.frame_id, cur.t))
        if not w.candidates:
            w.candidates.append(cur)
            return InitResult(False, reason="initialising: first frame")
        static = self._static(cur)
        if static is not None:
            return static
        prev = w.candidates[-1]
        m = self.matcher.match(features, prev.features)
        if len(m) < _MIN_MATCHES:
            w.candidates = [cur]
            w.frames = [(cur.frame_id, cur.t)]
            return InitResult(False, reason=f"initialising: {len(m)} matches with the previous candidate "
                                            f"(< {_MIN_MATCHES}), starting over")
        # the threshold in pixels of this camera (the settings' angle at its focal length)
        min_px = float(np.radians(s.min_parallax_deg)) * 0.5 * (camera.fx + camera.fy)
        parallax = self._rotation_free_parallax(cur, prev, m)
        if parallax >= min_px:
            matches = [FrameMatches.from_matches(prev.frame_id, m)]
            for older in w.candidates[-3:-1][::-1]:
                matches.append(FrameMatches.from_matches(older.frame_id, self.matcher.match(features, older.features)))
            w.candidates.append(replace(cur, matches=tuple(matches)))
        while w.candidates and cur.t - w.candidates[0].t > s.max_duration_s:
            w.candidates.pop(0)
        while len(w.candidates) > s.max_keyframes:
            # thin out, keeping the first and the newest: the span (and with it the IMU's
            # excitation) keeps growing up to max_duration_s however dense the candidates are
            gaps = np.diff([c.t for c in w.candidates])
            w.candidates.pop(1 + int(np.argmin(gaps[:-1] + gaps[1:])))
        w.frames = [(f, ft) for f, ft in w.frames if ft >= w.candidates[0].t]
        span = w.candidates[-1].t - w.candidates[0].t
        waiting = (f"initialising: {len(w.candidates)} of {s.min_keyframes} keyframes over {span:.2f} s "
                   f"(needs >= {s.min_duration_s} s and {min_px:.1f} px of parallax between them; "
                   "or a still start)")
        if w.last_failure:
            waiting += f"; last attempt: {w.last_failure}"
        if not (parallax >= min_px and s.dynamic and len(w.candidates) >= s.min_keyframes
                and span >= s.min_duration_s):
            return InitResult(False, reason=waiting)
        if defer:
            return InitResult(False, reason=waiting, attempt=True)
        result = self._dynamic()
        if not result.ok:  # a reconstruction failure may come from the oldest candidate: drop it
            self.refuse(result.reason, drop_oldest=result.alignment is None)
        return result
