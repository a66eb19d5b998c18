"""The poses of the frames between two keyframes of the odometry (in-between frames).

A frame between two keyframes is posed when it is processed (against the landmarks, by
:class:`~vio_depth.vio.VioEstimator`) and again, after every window update while both
keyframes are in the window, by the IMU between them: the prediction from the earlier
keyframe's state with its mismatch at the later keyframe spread linearly in time (a
bridge). The frames of an initialisation get their poses that way only after it succeeded
(retroactively): the offline backward pass of a run can use them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.geometry import adjoints, invert_transforms

from ..landmarks import LandmarkWindow
from .history import PoseHistory
from .imu_factors import ImuFactors

#: biases (accelerometer m/s^2, gyroscope rad/s) beyond which a kept preintegration is
#: integrated again rather than corrected to first order
_REINTEGRATE = (0.05, 0.005)


#: (``every_update`` False) a keyframe pair's frames are bridged again once the window knows the
#: pair's relative rotation or translation this much better (1-sigma) than when they were
#: bridged: a stale bridge with its stale covariance stays a consistent, only less certain,
#: estimate. Bridged once and never again, the street sample's frames 15-19 (bridged just after
#: the start, the scale 3 % off) kept relative poses 52-96 mm off (eager: 6-17 mm) and its
#: offline backward pass gave 2 fewer frames depth (docs/benchmarks.md "vio_realtime's worker:
#: iSAM2, and bridges only when learnt better")
RE_BRIDGE_SHRINK = 0.8


def _pair_covariance(w: LandmarkWindow, a: int, b: int) -> np.ndarray:
    """(6, 6) covariance of keyframes ``a`` and ``b``'s relative pose in ``w`` (rotation rad, then m)."""
    return PoseHistory.pair_covariance(w.pose(a), w.pose(b), w.joint_covariance([a, b]), 0, 1)


def _sigmas(C: np.ndarray) -> np.ndarray:
    """(2,) 1-sigma of a (6, 6) relative pose covariance's rotation (rad) and translation (m)."""
    return np.sqrt(np.maximum([np.trace(C[:3, :3]), np.trace(C[3:, 3:])], 0.0))


class FrameBridges:
    """The in-between frames of one session and their bridges (module docstring).

    Args:
        factors: the odometry's IMU factors (states of the window's keyframes, prediction).
        every_update: :meth:`refresh` poses every bridged frame again (True), or only the frames
            of keyframe pairs not posed yet or whose relative pose the window has learnt better
            since (False: ``VioSettings.bridge_every_update``; :data:`RE_BRIDGE_SHRINK`).
    """

    def __init__(self, factors: ImuFactors, every_update: bool = True):
        self.factors = factors
        self.every_update = bool(every_update)
        # frames posed again after every window update: (frame, t, keyframe before, keyframe after),
        # and those still waiting for the keyframe after: (frame, t, keyframe before)
        self._bridged: list[tuple[int, float, int, int]] = []
        self._unbridged: list[tuple[int, float, int]] = []
        # per (start, end) time: the preintegration (with the biases it was integrated at)
        # and the motion noise, kept while the frames are bridged
        self._pims: dict = {}
        self._motion_cov: dict = {}
        # (every_update False) the keyframe pairs whose frames were posed: their sigmas then
        self._done: dict[tuple[int, int], np.ndarray] = {}
        # a deferred refresh's arguments (:meth:`settle`), or None
        self._due: tuple | None = None

    def start(self, keyframes: list[tuple[int, float]], frames: list[tuple[int, float]]) -> None:
        """A new session from an initialisation: its ``keyframes`` and other ``frames``
        (``(id, t seconds)`` each); a frame between two keyframes is bridged between them, one
        after the newest keyframe (offered while the initialisation ran in a worker process)
        follows that keyframe (:meth:`add`)."""
        self._bridged, self._unbridged = [], []
        self._pims, self._motion_cov, self._done, self._due = {}, {}, {}, None
        for f, t in frames:
            before = [k for k, kt in keyframes if kt <= t]
            after = [k for k, kt in keyframes if kt > t]
            if before and after:
                self._bridged.append((f, t, before[-1], after[0]))
            elif before:
                self.add(f, t, before[-1])

    def add(self, frame_id: int, t: float, keyframe: int) -> None:
        """Frame ``frame_id`` at ``t`` seconds follows ``keyframe`` (the newest); it is bridged once
        the next keyframe comes (:meth:`close`)."""
        self._unbridged.append((int(frame_id), float(t), int(keyframe)))

    def following(self) -> list[tuple[int, float, int]]:
        """``(frame, t seconds, keyframe)`` of the frames after the newest keyframe (not bridged yet)."""
        return list(self._unbridged)

    def close(self, keyframe: int, t: float = float("inf")) -> None:
        """``keyframe`` (at ``t`` seconds) is new: the frames since the previous keyframe are
        bridged between the two. Frames after ``t`` (tracked while the window was refined in a
        worker process) now follow ``keyframe``; ``keyframe`` itself is no longer in between."""
        k = int(keyframe)
        self._bridged += [(f, ft, a, k) for f, ft, a in self._unbridged if ft < t and f != k]
        self._unbridged = [(f, ft, k) for f, ft, a in self._unbridged if ft > t and f != k]

    def settle(self) -> None:
        """Run the refresh a :meth:`refresh` with ``defer`` left (nothing when none is due)."""
        if self._due is not None:
            due, self._due = self._due, None
            self.refresh(*due)

    def refresh(self, window: LandmarkWindow, times: Mapping[int, float], history: PoseHistory,
                session: int, defer: bool = False) -> None:
        """Pose the bridged frames again from the window's latest estimate (``times``: seconds of
        the keyframes); frames whose keyframes left the window are kept as they are. ``defer``:
        only remember to, at :meth:`settle` (a later refresh replaces a deferred one).

        The frames of one keyframe pair are posed together (:meth:`_poses`): after every window
        update all of them are, some 60 frames for a 10-keyframe window, and one frame at a time
        this took 90 ms per update on the 752x564 ASL loop (2-core machine). Without
        ``every_update`` only the pairs not posed before or learnt better since are."""
        self._due = (window, times, history, session) if defer else None
        if defer:
            return
        ids = set(window.keyframe_ids)
        est = window.estimate
        keep = [(f, t, a, b) for f, t, a, b in self._bridged if a in ids and b in ids]
        groups: dict[tuple[int, int], list[tuple[int, float]]] = {}
        for f, t, a, b in keep:
            groups.setdefault((a, b), []).append((f, t))
        sigmas, covs = {}, {}
        if not self.every_update:
            covs = {g: _pair_covariance(window, *g) for g in groups}  # (reused by _poses)
            sigmas = {g: _sigmas(C) for g, C in covs.items()}
            groups = {g: frames for g, frames in groups.items()
                      if g not in self._done or np.any(sigmas[g] < RE_BRIDGE_SHRINK * self._done[g])}
        posed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for (a, b), frames in groups.items():
            posed.update(self._poses(window, est, times, a, b, frames, covs.get((a, b))))
        for f, _, _, b in keep:  # in the bridged order, as the history keeps its frames in order
            if f in posed:  # anchored to the later keyframe, which stays in the window longer
                history.add_frame(f, session, b, *posed[f])
        self._bridged = keep
        if not self.every_update:  # a pair is done once every frame of it has its bridge (a prediction
            # that failed, e.g. for want of IMU samples, is tried again at the next update)
            self._done.update({g: sigmas[g] for g, frames in groups.items() if all(f in posed for f, _ in frames)})
            self._done = {g: v for g, v in self._done.items() if g in sigmas}
        starts = {times[a] for _, _, a, _ in keep}
        ends = {times[b] for _, _, _, b in keep}
        self._pims = {k: v for k, v in self._pims.items() if k[0] in starts}
        self._motion_cov = {k: v for k, v in self._motion_cov.items() if k[1] in ends}

    def pose(self, window: LandmarkWindow, times: Mapping[int, float], t: float, a: int, b: int):
        """Camera pose (4, 4) of a frame at ``t`` between keyframes ``a`` and ``b`` and its
        covariance (6, 6) relative to ``b``, or ``(None, None)``.

        The IMU prediction from ``a``'s state, its mismatch at ``b`` spread linearly in time
        (a bridge). Covariance: the preintegration noise from ``t`` to ``b``, plus the share
        ``(1 - s)^2`` of the relative uncertainty of ``a`` and ``b`` (``s`` the fraction of
        the interval elapsed at ``t``).
        """
        return self._poses(window, window.estimate, times, a, b, [(0, t)]).get(0, (None, None))

    def _poses(self, w: LandmarkWindow, est, times: Mapping[int, float], a: int, b: int,
               frames: list[tuple[int, float]], C_ab: np.ndarray | None = None
               ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """:meth:`pose` of every frame ``(id, t)`` between keyframes ``a`` and ``b`` at once (the
        IMU prediction per frame, the bridge and the covariance as stacks): ``{id: (T_w_f,
        covariance)}`` of the frames that could be posed. ``C_ab``: the pair's relative pose
        covariance (:func:`_pair_covariance`) when the caller has it already, else None."""
        st, shared = self._pair(w, est, times, a, b, C_ab)
        if shared is None or not frames:
            return {}
        dR, dp, T_w_b, C_ab = shared
        t_b = times[b]
        ids, ts, ends, motion = [], [], [], []
        for f, t in frames:
            end, _, _ = self._predict(st, t)
            if end is None:
                continue
            if (t, t_b) not in self._motion_cov:  # noise of the camera's motion from t to b, in b
                self._motion_cov[(t, t_b)] = self.factors.predict(end, t_b)[1]
            ids.append(f)
            ts.append(t)
            ends.append(end.T_w_i)
            motion.append(self._motion_cov[(t, t_b)])
        if not ids:
            return {}
        s = (np.asarray(ts) - st.t) / max(t_b - st.t, 1e-12)  # (n,) fraction of the interval elapsed
        T = np.stack(ends)  # (n, 4, 4) IMU poses, the mismatch at b spread linearly in time
        T[:, :3, :3] = Rotation.from_rotvec(s[:, None] * dR).as_matrix() @ T[:, :3, :3]
        T[:, :3, 3] += s[:, None] * dp
        T_w_f = T @ self.factors.T_i_c
        A = adjoints(invert_transforms(T_w_f) @ T_w_b)  # (T_f_b)^-1 = T_b_f: covariances in f from b
        At = np.swapaxes(A, 1, 2)
        C = A @ np.stack(motion) @ At + ((1.0 - s) ** 2)[:, None, None] * (A @ C_ab @ At)
        C = 0.5 * (C + np.swapaxes(C, 1, 2))
        return {f: (T_w_f[k], C[k]) for k, f in enumerate(ids)}

    def _pair(self, w: LandmarkWindow, est, times: Mapping[int, float], a: int, b: int,
              C_ab: np.ndarray | None = None):
        """What the frames between keyframes ``a`` and ``b`` share: ``(a's state, (mismatch
        rotation vector, mismatch translation, T_w_b, covariance of a and b relative to each
        other) or None)``."""
        st = self.factors.state_of(est, a, times[a])
        end_b, _, _ = self._predict(st, times[b])
        shared = None
        if end_b is not None:
            T_b = self.factors.state_of(est, b, times[b]).T_w_i
            T_w_b = w.pose(b)
            C_ab = _pair_covariance(w, a, b) if C_ab is None else C_ab
            # the mismatch at b (rotation vector, translation), the same for all the pair's frames
            dR = Rotation.from_matrix(T_b[:3, :3] @ end_b.T_w_i[:3, :3].T).as_rotvec()
            shared = (dR, T_b[:3, 3] - end_b.T_w_i[:3, 3], T_w_b, C_ab)
        return st, shared

    def _predict(self, state, t: float):
        """The IMU prediction from ``state`` to ``t`` (without its covariance: ``(end, None,
        reason)``); the samples are integrated once per interval and again only when the
        biases moved by more than ``_REINTEGRATE`` since."""
        key = (state.t, t)
        hit = self._pims.get(key)
        if hit is not None and (np.linalg.norm(state.accel_bias - hit[1]) > _REINTEGRATE[0]
                                or np.linalg.norm(state.gyro_bias - hit[2]) > _REINTEGRATE[1]):
            hit = None
        if hit is None:
            pim, reason = self.factors.preintegrate(state, t)
            if pim is None:
                return None, None, reason
            hit = self._pims[key] = (pim, state.accel_bias.copy(), state.gyro_bias.copy())
        return self.factors.predict_with(hit[0], state, t, covariance=False)
