"""The poses the odometry estimated, and relative poses between any two of them with a covariance.

Every posed frame is stored relative to an **anchor keyframe**: ``T_anchor_f`` (fixed once
the frame is processed) and ``C_f``, the covariance of that relative pose. A keyframe is
its own anchor. The anchors' world poses follow the window's latest estimates
(:meth:`PoseHistory.update_keyframes`), so a frame's pose ``T_w_f = T_w_anchor T_anchor_f``
improves while its anchor is in the window and is frozen after.

Relative pose of frames ``a`` and ``b`` (right perturbation in ``b``, rotation first)::

    T_ab = T_w_a^-1 T_w_b
    xi_ab = eta_b - Ad(T_b^-1 T_a) eta_a + Ad(T_b^-1 T_rb) xi(ra -> rb)

with ``eta`` the frames' errors relative to their anchors ``ra``, ``rb`` (independent of
each other given the anchors) and ``xi(ra -> rb)`` the anchors' relative error: from the
window's joint marginal covariance when both are in it, else summed along the chain of
consecutive keyframes (each link's covariance as last seen in the window; correlations
between links are left out). Likewise ``T_ab`` itself: from the window's poses, else
composed along the chain of links (so that frames on both sides of the window's edge
stay consistent although a marginalised keyframe's world pose is frozen).

Frames of different **sessions** (the odometry was re-initialised in between) share no
world frame: their relative pose is refused.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.errors import ShapeError
from vio_core.geometry import adjoint, invert_transform


@dataclass(frozen=True)
class PoseRecord:
    """One posed frame. ``T_anchor_f``: (4, 4); ``covariance``: (6, 6) of it (right perturbation)."""

    session: int
    anchor: int
    T_anchor_f: np.ndarray
    covariance: np.ndarray


class PoseHistory:
    """Poses of the last ``max_frames`` posed frames and their anchors (module docstring)."""

    def __init__(self, max_frames: int = 20000):
        self.max_frames = int(max_frames)
        self._frames: OrderedDict[int, PoseRecord] = OrderedDict()
        self._kf_pose: dict[int, np.ndarray] = {}  # keyframe id -> latest T_w_c
        self._kf_session: dict[int, int] = {}
        # keyframe -> (previous keyframe, T_prev_k (4, 4), (6, 6) covariance), as last estimated together
        self._links: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self._window: tuple[list[int], np.ndarray] | None = None  # (ids, joint covariance) of the current window

    def __contains__(self, frame_id: int) -> bool:
        return frame_id in self._frames

    def __len__(self) -> int:
        return len(self._frames)

    # ------------------------------------------------------------------ writing
    def update_keyframes(self, session: int, ids, poses, joint_covariance) -> None:
        """The window's keyframes ``ids`` (oldest first), their (K, 4, 4) poses and (6K, 6K) joint covariance."""
        ids = [int(i) for i in ids]
        poses = check_array("poses", poses, (len(ids), 4, 4), finite=True)
        S = check_array("joint_covariance", joint_covariance, (6 * len(ids), 6 * len(ids)))
        for k, f in enumerate(ids):
            self._kf_pose[f] = poses[k].copy()
            self._kf_session[f] = session
            if f not in self._frames or self._frames[f].anchor != f:  # (a frame posed before it became a keyframe)
                self._frames[f] = PoseRecord(session, f, np.eye(4), np.zeros((6, 6)))
        for k in range(1, len(ids)):
            self._links[ids[k]] = (ids[k - 1], invert_transform(poses[k - 1]) @ poses[k],
                                   self.pair_covariance(poses[k - 1], poses[k], S, k - 1, k))
        self._window = (ids, S.copy())
        self._trim()

    def add_frame(self, frame_id: int, session: int, anchor: int, T_w_f, covariance) -> None:
        """A non-keyframe posed at ``T_w_f`` (4, 4) with ``covariance`` (6, 6) relative to keyframe ``anchor``."""
        T_w_f = check_transform("T_w_f", T_w_f)
        C = check_array("covariance", covariance, (6, 6), finite=True)
        T_a = self._kf_pose[anchor]
        self._frames[int(frame_id)] = PoseRecord(session, int(anchor), invert_transform(T_a) @ T_w_f, C.copy())
        self._frames.move_to_end(int(frame_id))
        self._trim()

    def _trim(self) -> None:
        while len(self._frames) > self.max_frames:
            self._frames.popitem(last=False)
        if len(self._kf_pose) > self.max_frames:
            oldest = min(r.anchor for r in self._frames.values())
            for k in [k for k in self._kf_pose if k < oldest]:
                self._kf_pose.pop(k)
                self._kf_session.pop(k, None)
                self._links.pop(k, None)

    # ------------------------------------------------------------------ reading
    def pose(self, frame_id: int) -> np.ndarray | None:
        """(4, 4) latest world pose of a stored frame, or None."""
        r = self._frames.get(frame_id)
        return None if r is None else self._kf_pose[r.anchor] @ r.T_anchor_f

    def sessions(self) -> dict[int, int]:
        """Posed frames per session."""
        out: dict[int, int] = {}
        for r in self._frames.values():
            out[r.session] = out.get(r.session, 0) + 1
        return out

    def session(self, frame_id: int) -> int | None:
        r = self._frames.get(frame_id)
        return None if r is None else r.session

    @staticmethod
    def pair_covariance(T_a, T_b, S, i: int, j: int) -> np.ndarray:
        """(6, 6) covariance of the relative pose ``T_a^-1 T_b`` (right perturbation in b).

        Args:
            T_a, T_b: (4, 4) camera-to-world poses of two keyframes, metres.
            S: (6V, 6V) their joint covariance with other views (world right perturbations,
                rotation rad first, then translation m; e.g. ``LandmarkWindow.joint_covariance``).
            i, j: the rows (in 6-blocks) of ``T_a`` and ``T_b`` in ``S``.

        Returns:
            (6, 6) covariance, rotation rad^2 first, then translation m^2, symmetric.
        """
        T_a, T_b = check_array("T_a", T_a, (4, 4)), check_array("T_b", T_b, (4, 4))
        S = check_array("S", S, (None, None))
        if S.shape[0] != S.shape[1] or S.shape[0] % 6 or not (0 <= i < S.shape[0] // 6 and 0 <= j < S.shape[0] // 6):
            raise ShapeError(f"pair_covariance: S must be (6V, 6V) with views {i} and {j} in it, got {S.shape}")
        Sa, Sb = S[6 * i:6 * i + 6, 6 * i:6 * i + 6], S[6 * j:6 * j + 6, 6 * j:6 * j + 6]
        Sab = S[6 * i:6 * i + 6, 6 * j:6 * j + 6]
        A = adjoint(invert_transform(T_b) @ T_a)
        C = Sb + A @ Sa @ A.T - A @ Sab - Sab.T @ A.T
        return 0.5 * (C + C.T)

    def _anchor_relative(self, ra: int, rb: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(T_ra_rb (4, 4), its covariance (6, 6) in rb)``, or ``(None, None)`` when not linked.

        Both in the window: from its current poses and joint covariance. Otherwise along the
        chain of links (each the relative pose of two consecutive keyframes as last estimated
        together): frames anchored on both sides of the window's edge then stay consistent
        with each other although the marginalised keyframe's world pose is frozen.
        """
        if ra == rb:
            return np.eye(4), np.zeros((6, 6))
        if self._window is not None:
            ids, S = self._window
            if ra in ids and rb in ids:
                T_a, T_b = self._kf_pose[ra], self._kf_pose[rb]
                return invert_transform(T_a) @ T_b, self.pair_covariance(T_a, T_b, S, ids.index(ra), ids.index(rb))
        lo, hi = min(ra, rb), max(ra, rb)
        T = np.eye(4)  # T_lo_hi, built from hi downwards: T = T_{k-1,k} T
        C = np.zeros((6, 6))  # covariance in hi's frame
        k = hi
        while k != lo:
            link = self._links.get(k)
            if link is None:
                return None, None
            prev, T_prev_k, C_k = link
            A = adjoint(invert_transform(T))  # error of link k (in k) -> in hi: Ad(T_k_hi^-1) = Ad(T_hi_k)
            C = C + A @ C_k @ A.T
            T = T_prev_k @ T
            k = prev
            if k < lo:
                return None, None
        if ra > rb:  # the inverse relative pose: xi' = -Ad(T_rb_ra) xi
            A = adjoint(T)
            return invert_transform(T), A @ C @ A.T
        return T, C

    def window_span_sigma(self) -> tuple[float, float]:
        """``(sigma, distance)`` metres: the 1-sigma along the line between the window's oldest and
        newest keyframe (from the joint covariance) and their distance; ``(0, 0)`` for a single
        keyframe, ``(inf, 0)`` without a window.
        ``sigma / distance`` is how well the window knows the metric scale."""
        if self._window is None:
            return float("inf"), 0.0
        if len(self._window[0]) < 2:
            return 0.0, 0.0  # one keyframe: no span to be unsure about
        ids, S = self._window
        return self.span_sigma(self._kf_pose[ids[0]], self._kf_pose[ids[-1]], S, 0, len(ids) - 1)

    @staticmethod
    def span_sigma(T_a, T_b, S, i: int, j: int) -> tuple[float, float]:
        """``(sigma, distance)`` metres of the span from ``T_a`` to ``T_b``: the 1-sigma of the
        relative pose's translation along the span (:meth:`pair_covariance`; the RMS over the
        axes when the two coincide) and the span's length. Arguments as :meth:`pair_covariance`."""
        C = PoseHistory.pair_covariance(T_a, T_b, S, i, j)
        d_b = T_b[:3, :3].T @ (T_b[:3, 3] - T_a[:3, 3])  # the displacement in b's frame (where the error lives)
        n = float(np.linalg.norm(d_b))
        u = d_b / n if n > 0 else np.zeros(3)
        sigma = float(np.sqrt(max(u @ C[3:, 3:] @ u, 0.0))) if n > 0 else float(np.sqrt(np.trace(C[3:, 3:]) / 3))
        return sigma, n

    def relative(self, a: int, b: int) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """``(T_ab (4, 4), covariance (6, 6), "")`` of stored frames ``a`` and ``b``, or ``(None, None, reason)``."""
        ra_rec, rb_rec = self._frames.get(a), self._frames.get(b)
        if ra_rec is None or rb_rec is None:
            missing = a if ra_rec is None else b
            return None, None, f"the odometry has no pose for frame {missing}"
        if ra_rec.session != rb_rec.session:
            return None, None, (f"the odometry was re-initialised between frames {min(a, b)} and {max(a, b)}: "
                                "no common world frame")
        T_rr, C_anchor = self._anchor_relative(ra_rec.anchor, rb_rec.anchor)
        if T_rr is None:
            return None, None, f"frames {a} and {b} are too far apart in the odometry's history"
        T_ab = invert_transform(ra_rec.T_anchor_f) @ T_rr @ rb_rec.T_anchor_f
        A_a = adjoint(invert_transform(T_ab))
        A_r = adjoint(invert_transform(rb_rec.T_anchor_f))
        C = rb_rec.covariance + A_a @ ra_rec.covariance @ A_a.T + A_r @ C_anchor @ A_r.T
        return T_ab, 0.5 * (C + C.T), ""
