"""Sliding-window refinement of keyframe poses and landmarks with gtsam.

The window holds the newest ``window_keyframes`` keyframes. Each new keyframe:

1. joins the :class:`~vio_depth.landmarks.tracks.TrackTable` through its matches;
2. enters the factor graph with its **pose priors** (:class:`PosePriorSettings`): an
   absolute ``PriorFactorPose3`` and a ``BetweenFactorPose3`` to the previous keyframe
   carrying the sequence's relative motion -- or, with a :class:`MotionFactorSource`
   (IMU preintegration), whatever factors that source adds between the two keyframes;
3. every track with two or more observations is triangulated over the window
   (:func:`triangulation.multiview.triangulate_tracks`, with the poses' current
   uncertainty); its outlier observations are split off the track, and the VALID ones
   become ``Point3`` landmarks with ``GenericProjectionFactorCal3DS2`` factors (raw pixels,
   the camera's distortion; Huber kernel);
4. Levenberg-Marquardt refines poses and landmarks together; the scale is held by the
   priors (or the motion factors), never by the images;
5. the keyframe poses' joint marginal covariance comes from ``gtsam.Marginals``, and each
   landmark's point, covariance and depth (with sigma) in every keyframe observing it
   from a final multi-view triangulation at the refined poses with those covariances;
6. beyond ``window_keyframes`` the oldest keyframe is **marginalised**: its projection
   factors are dropped (their landmarks keep their other observations; OKVIS-style, to
   keep the graph sparse), and its other factors (priors, motion factors, earlier
   marginals) are eliminated into a linear marginal factor on the keys they share with
   the rest of the window (``LinearContainerFactor``). Memory is bounded by the window.

Query (:meth:`LandmarkWindow.query`): a keyframe reads its landmarks directly; another
frame associates its keypoints with tracks through its matches, its pose prior is
corrected like its newest keyframe's and then refined against the landmarks
(:func:`~vio_depth.landmarks.resection.refine_pose`), and the landmarks' depths follow
with a first-order sigma (:func:`triangulation.multiview.depth_in_view`).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.multiview import MultiviewPoints, TrackStatus, depth_in_view, triangulate_tracks
from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import invert_transform

from .resection import refine_pose
from .settings import LandmarkSettings
from .tracks import TrackTable
from .types import KeyframeInput, LandmarkPoints, MotionFactorSource, WindowUpdate


@dataclass
class _Keyframe:
    info: KeyframeInput
    extra_keys: list


def _pose_noise(gtsam, rot_sigma_rad: float, trans_sigma_m: float):
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([rot_sigma_rad] * 3 + [trans_sigma_m] * 3))


def _calibration(gtsam, camera: Camera):
    if camera.model != "radtan":
        return None  # e.g. equidistant (fisheye): not Cal3DS2's model (use ideal pixels instead)
    d = camera.dist
    if len(d) > 4 and any(x != 0 for x in d[4:]):
        return None  # k3 and beyond: not representable by Cal3DS2 (use ideal pixels instead)
    k1, k2, p1, p2 = (tuple(d) + (0.0,) * 4)[:4]
    return gtsam.Cal3DS2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy, k1, k2, p1, p2)


class LandmarkWindow:
    """gtsam sliding window over keyframes (see the module docstring)."""

    def __init__(self, settings: LandmarkSettings = LandmarkSettings(), motion_factors: MotionFactorSource | None = None):
        import gtsam  # optional heavy dependency, imported where it is used

        self._gtsam = gtsam
        self.settings = settings
        self.motion_factors = motion_factors
        if settings.pose_prior is None:
            raise SettingsError("LandmarkSettings.pose_prior is not resolved: use settings.resolved(pose_kind) "
                                "(the pipeline takes the sequence's kind of poses)")
        if motion_factors is None and not settings.pose_prior.absolute_on_every_keyframe:
            raise InputError("landmarks: pose priors on the first keyframe only need a MotionFactorSource (IMU)")
        self.tracks = TrackTable()
        self._kf: OrderedDict[int, _Keyframe] = OrderedDict()
        self._values = gtsam.Values()
        self._factors: list = []  # (frozenset of keys, nonlinear factor): priors, motion, marginals
        self._joint_cov = np.zeros((0, 0))  # (6K, 6K) joint covariance of the keyframe poses
        self._landmarks: MultiviewPoints | None = None
        self._obs = None  # observations behind self._landmarks

    # ------------------------------------------------------------------ state
    @property
    def keyframe_ids(self) -> list[int]:
        """Frame ids of the window's keyframes, oldest first."""
        return list(self._kf)

    def keyframe(self, frame_id: int) -> KeyframeInput:
        return self._kf[frame_id].info

    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) refined camera-to-world pose of a keyframe of the window."""
        from gtsam.symbol_shorthand import X

        return self._values.atPose3(X(frame_id)).matrix()

    def pose_covariance(self, frame_id: int) -> np.ndarray:
        """(6, 6) marginal covariance of a keyframe's pose in the world (rotation rad, translation m)."""
        i = 6 * self.keyframe_ids.index(frame_id)
        return self._joint_cov[i:i + 6, i:i + 6].copy()

    def relative_covariances(self, reference: int | None = None) -> np.ndarray:
        """(K, 6, 6) covariance of every keyframe pose given the ``reference`` keyframe's.

        The conditional covariance ``S_ii - S_ir S_rr^-1 S_ri`` of the joint marginal: how
        uncertain each pose is *relative to* the reference (default: the newest keyframe),
        which is what triangulation and depths depend on; the absolute (gauge) uncertainty
        shared by all poses cancels. The reference's own block is (numerically) zero.
        """
        ids = self.keyframe_ids
        r = 6 * ids.index(ids[-1] if reference is None else reference)
        S = self._joint_cov
        S_rr = S[r:r + 6, r:r + 6] + 1e-15 * np.eye(6)
        S_xr = S[:, r:r + 6]
        cond = S - S_xr @ np.linalg.solve(S_rr, S_xr.T)
        cond = 0.5 * (cond + cond.T)
        blocks = np.stack([cond[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(len(ids))])
        return blocks + 1e-12 * np.eye(6)

    def joint_covariance(self, frame_ids) -> np.ndarray:
        """(6K, 6K) joint marginal covariance of the poses of keyframes ``frame_ids`` (in that order)."""
        ids = self.keyframe_ids
        rows = np.concatenate([np.arange(6 * ids.index(f), 6 * ids.index(f) + 6) for f in frame_ids])
        return self._joint_cov[np.ix_(rows, rows)].copy()

    @property
    def estimate(self):
        """The window's current ``gtsam.Values`` (a copy)."""
        return self._gtsam.Values(self._values)

    def landmarks(self) -> MultiviewPoints | None:
        """The last multi-view solution over the window (tracks with >= 2 observations)."""
        return self._landmarks

    def factor_count(self) -> int:
        """Non-visual factors held (priors, motion and marginal factors): bounded by the window."""
        return len(self._factors)

    # ------------------------------------------------------------------ keyframes
    def _prior_covariance(self, translation_m: float) -> np.ndarray:
        """(6, 6) prior covariance of a pose relative to another ``translation_m`` away: the
        relative prior, or twice the absolute prior's variance where that is smaller (two
        independent absolute errors)."""
        p = self.settings.pose_prior
        var = p.relative_sigmas(translation_m) ** 2
        if p.absolute_on_every_keyframe:
            a = np.array([np.radians(p.absolute_rotation_deg)] * 3 + [p.absolute_translation_m] * 3)
            var = np.minimum(var, 2.0 * a * a)
        return np.diag(var)

    def add_keyframe(self, kf: KeyframeInput) -> WindowUpdate:
        """Insert a keyframe, refine the window, marginalise the oldest keyframe beyond it."""
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import X

        fid = int(kf.frame_id)
        if fid in self._kf or (self._kf and fid <= next(reversed(self._kf))):
            raise InputError(f"landmarks: keyframe ids must increase, got {fid} after {self.keyframe_ids}")
        p = self.settings.pose_prior
        prev = self._kf[next(reversed(self._kf))].info if self._kf else None
        first = prev is None

        new_values = gtsam.Values()
        extra = []
        if self.motion_factors is not None:
            extra = list(self.motion_factors.extra_keys(fid))
            graph, values = self.motion_factors.factors(prev, kf, self._values)
            for i in range(graph.size()):
                f = graph.at(i)
                self._factors.append((frozenset(f.keys()), f))
            new_values.insert(values)
        # a motion factor source may anchor the first keyframe itself (VIO: a prior on yaw and
        # position only, roll and pitch being observable through gravity)
        anchored = bool(getattr(self.motion_factors, "anchors_first_keyframe", False))
        if kf.T_w_c is not None:
            if (first and not anchored) or p.absolute_on_every_keyframe:
                noise = _pose_noise(gtsam, np.radians(p.absolute_rotation_deg), p.absolute_translation_m)
                self._factors.append((frozenset([X(fid)]), gtsam.PriorFactorPose3(X(fid), gtsam.Pose3(kf.T_w_c), noise)))
            if prev is not None and p.absolute_on_every_keyframe and prev.T_w_c is not None:
                T_rel = invert_transform(prev.T_w_c) @ kf.T_w_c
                noise = gtsam.noiseModel.Diagonal.Sigmas(p.relative_sigmas(float(np.linalg.norm(T_rel[:3, 3]))))
                self._factors.append((frozenset([X(prev.frame_id), X(fid)]),
                                      gtsam.BetweenFactorPose3(X(prev.frame_id), X(fid), gtsam.Pose3(T_rel), noise)))
            if not new_values.exists(X(fid)):
                # initial value: the prior, corrected like the previous keyframe's
                T0 = kf.T_w_c if first or prev.T_w_c is None else (
                    self.pose(prev.frame_id) @ invert_transform(prev.T_w_c) @ kf.T_w_c)
                new_values.insert(X(fid), gtsam.Pose3(T0))
        if not new_values.exists(X(fid)):
            raise InputError(f"landmarks: keyframe {fid} has no pose prior and no motion factor gave one")
        self._values.insert(new_values)
        self._kf[fid] = _Keyframe(kf, extra)
        step = 0.0 if prev is None or prev.T_w_c is None or kf.T_w_c is None else float(
            np.linalg.norm((invert_transform(prev.T_w_c) @ kf.T_w_c)[:3, 3]))
        # joint covariance before refinement: the new pose is the previous one plus the
        # relative prior's uncertainty (the first one: its absolute prior)
        K = len(self._joint_cov)
        J = np.zeros((K + 6, K + 6))
        J[:K, :K] = self._joint_cov
        if prev is None:
            a, t = np.radians(p.absolute_rotation_deg), p.absolute_translation_m
            J[K:, K:] = np.diag([a * a] * 3 + [t * t] * 3)
        else:
            J[K:, :K] = self._joint_cov[K - 6:K, :]
            J[:K, K:] = self._joint_cov[:, K - 6:K]
            J[K:, K:] = self._joint_cov[K - 6:K, K - 6:K] + self._prior_covariance(step)
        self._joint_cov = J
        self.tracks.add_frame(fid, kf.keypoints, list(kf.matches))

        update = self._optimise(fid)
        shift = self._pose_shift_sigmas()
        marg = None
        if len(self._kf) > self.settings.window_keyframes:
            marg = next(iter(self._kf))
            self._marginalise(marg)
            # a motion factor source may re-anchor the unobservable directions (VIO: yaw and
            # position) on the new oldest keyframe, so that the window cannot drift along them
            hook = getattr(self.motion_factors, "after_marginalisation", None)
            if hook is not None:
                graph = hook(next(iter(self._kf)), self._values)
                for i in range(graph.size()):
                    f = graph.at(i)
                    self._factors.append((frozenset(f.keys()), f))
        # the landmarks of the (possibly shrunk) window at the refined poses and covariances
        _, lm = self._triangulate()
        self._landmarks = lm
        good = lm.inlier & lm.valid[lm.obs_track]
        return WindowUpdate(**{**update.__dict__, "marginalised": marg, "keyframes": len(self._kf),
                               "landmarks": int(lm.valid.sum()), "pose_shift_sigmas": shift,
                               "median_residual_px": float(np.median(lm.residual_px[good])) if good.any()
                               else float("nan")})

    # ------------------------------------------------------------------ optimisation
    def _views(self):
        ids = self.keyframe_ids
        T = np.stack([self.pose(f) for f in ids])
        C = self.relative_covariances()
        cams = [self._kf[f].info.camera for f in ids]
        return ids, T, C, cams

    def _triangulate(self):
        obs = self.tracks.observations(min_length=self.settings.min_track_length)
        ids, T, C, cams = self._views()
        view = np.searchsorted(np.array(ids), obs.frame) if len(obs) else np.zeros(0, np.int64)
        res = triangulate_tracks(obs.track, view, obs.uv, cams, T, self.settings.multiview, C)
        self._obs = obs
        return obs, res

    def _optimise(self, new_id: int) -> WindowUpdate:
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import L, X

        s = self.settings
        if s.pose_prior.absolute_on_every_keyframe and s.restart_from_priors:
            # every refinement starts from the priors: a window that went astray (e.g. while
            # it had too few keyframes to fix the scale) does not carry its error forward
            for f, k in self._kf.items():
                if k.info.T_w_c is not None:
                    self._values.update(X(f), gtsam.Pose3(k.info.T_w_c))
        obs, mv = self._triangulate()
        # per-track outlier rejection: observations outside the gate leave their track
        out = ~mv.inlier & (mv.status[mv.obs_track] != TrackStatus.TOO_FEW_VIEWS)
        out &= np.isin(mv.status[mv.obs_track], (TrackStatus.VALID, TrackStatus.UNCERTAIN, TrackStatus.DEPTH_RANGE))
        detached = int(out.sum())
        if detached:
            self.tracks.detach(obs.frame[out], obs.keypoint[out])

        graph = gtsam.NonlinearFactorGraph()
        for _, f in self._factors:
            graph.add(f)
        values = self._non_landmark_values()
        # landmarks of the graph: VALID tracks, and tracks that are UNCERTAIN only because
        # the poses are not refined yet (up to ba_relative_sigma_factor x the bound)
        in_graph = mv.valid | ((mv.status == TrackStatus.UNCERTAIN)
                               & (mv.relative_sigma <= s.ba_relative_sigma_factor * s.multiview.max_relative_sigma))
        if in_graph.sum() > s.ba_max_landmarks:
            # the refinement needs enough landmarks to fix the poses, not all of them (all are
            # triangulated afterwards at the refined poses): keep the longest tracks, then
            # the most certain
            rows = np.nonzero(in_graph)[0]
            order = np.lexsort((mv.relative_sigma[rows], -mv.n_inliers[rows]))
            in_graph = np.zeros_like(in_graph)
            in_graph[rows[order[: s.ba_max_landmarks]]] = True
        use = mv.inlier & in_graph[mv.obs_track]
        lm_rows = np.nonzero(in_graph)[0]
        for r in lm_rows:
            values.insert(L(int(mv.track_ids[r])), gtsam.Point3(*mv.points_w[r]))
        pix = s.multiview.pixel_sigma_px
        robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(s.huber_sigmas),
                                                gtsam.noiseModel.Isotropic.Sigma(2, pix))
        cals = {f: _calibration(gtsam, k.info.camera) for f, k in self._kf.items()}
        idx = np.nonzero(use)[0]
        tids = mv.track_ids[mv.obs_track[idx]]
        for i, tid in zip(idx, tids):
            f = int(obs.frame[i])
            cal = cals[f]
            if cal is None:
                cam = self._kf[f].info.camera
                uv = cam.undistort_points(obs.uv[i:i + 1])[0]
                cal_use = gtsam.Cal3DS2(cam.fx, cam.fy, 0.0, cam.cx, cam.cy, 0.0, 0.0, 0.0, 0.0)
            else:
                uv, cal_use = obs.uv[i], cal
            graph.add(gtsam.GenericProjectionFactorCal3DS2(np.asarray(uv, float), robust, X(f), L(int(tid)), cal_use))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(s.lm_max_iterations)
        before = graph.error(values)
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        except RuntimeError:  # indeterminant system: keep the previous estimate
            result = values
        after = graph.error(result)
        self._values = self._non_landmark_values(result)
        try:
            marginals = gtsam.Marginals(graph, result)
            ids = self.keyframe_ids
            J = marginals.jointMarginalCovariance(gtsam.KeyVector([X(f) for f in ids])).fullMatrix()
            self._joint_cov = 0.5 * (J + J.T)
        except RuntimeError:
            pass
        return WindowUpdate(new_id, len(self._kf), 0, int(use.sum()), detached, None,
                            mv.status_counts(), float(before), float(after))

    def _pose_shift_sigmas(self) -> float:
        p = self.settings.pose_prior
        sig = np.array([np.radians(p.absolute_rotation_deg)] * 3 + [p.absolute_translation_m] * 3)
        worst = 0.0
        for f, k in self._kf.items():
            if k.info.T_w_c is None:
                continue
            d = invert_transform(k.info.T_w_c) @ self.pose(f)
            rot = Rotation.from_matrix(d[:3, :3]).as_rotvec()
            worst = max(worst, float(np.sqrt(np.mean((np.r_[rot, d[:3, 3]] / sig) ** 2))))
        return worst

    def _non_landmark_values(self, source=None):
        """Values of every non-landmark key (poses, motion-source keys) of ``source``."""
        gtsam = self._gtsam
        source = self._values if source is None else source
        keys = [k for k in source.keys() if gtsam.Symbol(k).chr() != ord("l")]
        return _subset(gtsam, source, keys)

    def _marginalise(self, frame_id: int) -> None:
        """Marginalise a keyframe: drop its projections, eliminate its other factors."""
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import X

        old = {X(frame_id), *self._kf[frame_id].extra_keys}
        touching = [(k, f) for k, f in self._factors if k & old]
        self._factors = [(k, f) for k, f in self._factors if not k & old]
        if touching and self.motion_factors is not None:
            graph = gtsam.NonlinearFactorGraph()
            for _, f in touching:
                graph.add(f)
            keys = set().union(*(k for k, _ in touching))
            lin_point = _subset(gtsam, self._values, sorted(keys))
            linear = graph.linearize(lin_point)
            ordering = gtsam.Ordering()
            for k in sorted(old & keys):
                ordering.push_back(k)
            _, remaining = linear.eliminatePartialSequential(ordering)
            for i in range(remaining.size()):
                g = remaining.at(i)
                if g is None or not len(g.keys()):
                    continue
                point = _subset(gtsam, self._values, list(g.keys()))
                self._factors.append((frozenset(g.keys()), gtsam.LinearContainerFactor(g, point)))
        for k in old:
            if self._values.exists(k):
                self._values.erase(k)
        i = 6 * self.keyframe_ids.index(frame_id)
        keep = np.r_[0:i, i + 6:len(self._joint_cov)]
        self._joint_cov = self._joint_cov[np.ix_(keep, keep)]
        self._kf.pop(frame_id)
        self.tracks.remove_frame(frame_id)

    # ------------------------------------------------------------------ query
    def query(self, camera: Camera, T_w_c, keypoints, matches=(), frame_id: int | None = None,
              prior_covariance=None) -> LandmarkPoints:
        """Metric landmark points seen by a frame (see the module docstring).

        Args:
            camera: the frame's camera.
            T_w_c: (4, 4) the frame's pose prior (camera-to-world, metres), or None for a
                keyframe of the window (its refined pose is used).
            keypoints: (N, 2) raw pixels of the frame's keypoints.
            matches: :class:`FrameMatches` with keyframes of the window (not needed for a
                keyframe of the window).
            frame_id: the frame's id; when it is a keyframe of the window its
                observations are read directly.
            prior_covariance: (6, 6) covariance of ``T_w_c`` relative to the newest matched
                keyframe (e.g. an IMU prediction's), or None: the relative pose prior of the
                settings.

        Returns:
            :class:`LandmarkPoints` (possibly empty, with a reason).
        """
        kp = check_array("keypoints", keypoints, (None, 2))
        lm = self._landmarks
        if not len(self._kf):
            return LandmarkPoints.empty("no keyframe in the window yet", T_w_c)
        if frame_id is not None and frame_id in self._kf:
            rel_cov = self.relative_covariances()[self.keyframe_ids.index(frame_id)]
            obs = self._obs
            sel = np.zeros(0, bool) if lm is None else (obs.frame == frame_id) & lm.inlier & lm.valid[lm.obs_track]
            if not sel.any():
                out = LandmarkPoints.empty("no landmark of the window qualifies in this keyframe", self.pose(frame_id))
                return LandmarkPoints(**{**out.__dict__, "covariance": rel_cov})
            return LandmarkPoints(obs.uv[sel], lm.depth[sel], lm.sigma_depth[sel], obs.track[sel],
                                  self.pose(frame_id), int(sel.sum()), True, "", rel_cov, obs.keypoint[sel])
        if T_w_c is None:
            raise InputError("landmarks: a frame that is not a keyframe of the window needs a pose prior")
        T_prior = check_transform("T_w_c", T_w_c)
        matches = [m for m in matches if m.keyframe in self._kf]
        # prior: corrected like the newest matched keyframe, uncertain by the relative prior
        ref = max((m.keyframe for m in matches), default=next(reversed(self._kf)))
        ref_info = self._kf[ref].info
        T0 = T_prior if ref_info.T_w_c is None else self.pose(ref) @ invert_transform(ref_info.T_w_c) @ T_prior
        step = float(np.linalg.norm((invert_transform(T0) @ self.pose(ref))[:3, 3]))
        motion_cov = self._prior_covariance(step) if prior_covariance is None else check_array(
            "prior_covariance", prior_covariance, (6, 6), finite=True)
        prior_cov = self.relative_covariances()[self.keyframe_ids.index(ref)] + motion_cov

        def empty(reason):
            out = LandmarkPoints.empty(reason, T0)
            return LandmarkPoints(**{**out.__dict__, "covariance": prior_cov})

        if lm is None or len(lm.track_ids) == 0:
            return empty("the window has no landmark yet")
        tracks = self.tracks.associate(matches, len(kp))
        rows = np.clip(np.searchsorted(lm.track_ids, tracks), 0, len(lm.track_ids) - 1)
        has = (tracks >= 0) & (lm.track_ids[rows] == tracks) & lm.valid[rows]
        n_assoc = int(has.sum())
        if n_assoc == 0:
            return empty("no keypoint of this frame is associated with a landmark")
        kp_idx = np.nonzero(has)[0]
        r = rows[kp_idx]
        P, C = lm.points_w[r], lm.covariance_w[r]
        T, cov, refined = T0, prior_cov, False
        s = self.settings
        if n_assoc >= s.min_query_points and s.query_max_iterations > 0:
            ref_pose = refine_pose(P, C, kp[kp_idx], camera, T0, prior_cov, s.multiview.pixel_sigma_px,
                                   s.huber_sigmas, s.query_max_iterations)
            T, cov, refined = ref_pose.T_w_c, ref_pose.covariance, True
            inl = ref_pose.inlier & (ref_pose.whitened_residual <= s.multiview.max_residual_sigmas)
        else:
            inl = np.ones(len(kp_idx), bool)
        depth, sigma = depth_in_view(P, C, T, cov)
        ok = inl & (depth > 0) & (sigma <= s.multiview.max_relative_sigma * np.maximum(depth, 1e-12))
        reason = "" if ok.any() else "no associated landmark passed the residual and uncertainty gates"
        if not refined:
            reason = (reason + "; " if reason else "") + f"pose not refined ({n_assoc} landmarks < {s.min_query_points})"
        return LandmarkPoints(kp[kp_idx][ok], depth[ok], sigma[ok], tracks[kp_idx][ok], T, n_assoc, refined, reason,
                              cov, kp_idx[ok])


def _subset(gtsam, values, keys):
    """A copy of ``values`` restricted to ``keys`` (any value types)."""
    out = gtsam.Values(values)
    wanted = set(keys)
    for k in list(out.keys()):
        if k not in wanted:
            out.erase(k)
    return out
