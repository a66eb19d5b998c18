"""The window's factor graph and its Levenberg-Marquardt refinement: :class:`WindowGraph`.

Holds the current estimate (``gtsam.Values`` of the keyframe poses ``X(f)`` and the
motion source's keys) and the non-visual factors (the motion source's, marginals). A
refinement adds, for the landmarks chosen by :func:`select_landmarks`, ``Point3`` values
and ``GenericProjectionFactorCal3DS2`` factors (raw pixels with the camera's distortion
where Cal3DS2 represents it, else ideal pixels; Huber kernel), runs Levenberg-Marquardt
over poses, motion keys and landmarks together, keeps the non-landmark values, and reads
the keyframe poses' joint marginal covariance (``gtsam.Marginals``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from triangulation.multiview import MultiviewPoints, TrackStatus
from vio_core.camera import Camera

from .marginalisation import marginalise_factors, subset_values
from .settings import LandmarkSettings


def calibration(camera: Camera):
    """``gtsam.Cal3DS2`` of a radtan camera with at most (k1, k2, p1, p2), else None (use ideal pixels)."""
    import gtsam

    if camera.model != "radtan":
        return None  # e.g. equidistant (fisheye): not Cal3DS2's model (use ideal pixels instead)
    d = camera.dist
    if len(d) > 4 and any(x != 0 for x in d[4:]):
        return None  # k3 and beyond: not representable by Cal3DS2 (use ideal pixels instead)
    k1, k2, p1, p2 = (tuple(d) + (0.0,) * 4)[:4]
    return gtsam.Cal3DS2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy, k1, k2, p1, p2)


def projection_pixels(camera: Camera, uv: np.ndarray):
    """``(pixels (N, 2), gtsam.Cal3DS2)`` for projection factors of ``uv: (N, 2)`` raw pixels:
    the raw pixels with the camera's :func:`calibration`, or, where Cal3DS2 cannot model its
    distortion, ideal (undistorted) pixels with a distortion-free calibration."""
    import gtsam

    cal = calibration(camera)
    if cal is None:
        return camera.undistort_points(uv), gtsam.Cal3DS2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy,
                                                          0.0, 0.0, 0.0, 0.0)
    return uv, cal


def select_landmarks(mv: MultiviewPoints, settings: LandmarkSettings) -> np.ndarray:
    """(T,) bool: the tracks of ``mv`` that enter the refinement as landmarks.

    VALID tracks, and tracks UNCERTAIN only because the poses are not refined yet (up to
    ``ba_relative_sigma_factor`` x the bound); at most ``ba_max_landmarks``: the refinement
    needs enough landmarks to fix the poses, not all of them (all are triangulated
    afterwards at the refined poses), so the longest tracks, then the most certain.
    """
    s = settings
    in_graph = mv.valid | ((mv.status == TrackStatus.UNCERTAIN)
                           & (mv.relative_sigma <= s.ba_relative_sigma_factor * s.multiview.max_relative_sigma))
    if in_graph.sum() > s.ba_max_landmarks:
        rows = np.nonzero(in_graph)[0]
        order = np.lexsort((mv.relative_sigma[rows], -mv.n_inliers[rows]))
        in_graph = np.zeros_like(in_graph)
        in_graph[rows[order[: s.ba_max_landmarks]]] = True
    return in_graph


@dataclass(frozen=True)
class Refinement:
    """Outcome of :meth:`WindowGraph.refine`.

    Attributes:
        observations: projection factors in the graph.
        error_before / error_after: the graph's error at the start and at the result.
        joint_covariance: (6K, 6K) joint marginal covariance of the keyframe poses (in the
            order asked for), or None when gtsam could not compute it.
    """

    observations: int
    error_before: float
    error_after: float
    joint_covariance: np.ndarray | None


class WindowGraph:
    """The estimate and the non-visual factors of the window (module docstring)."""

    def __init__(self):
        import gtsam  # optional heavy dependency, imported where it is used

        self._gtsam = gtsam
        self.values = gtsam.Values()
        self.factors: list = []  # (frozenset of keys, nonlinear factor): priors, motion, marginals
        # the projection factors of the last refinement, reused by the next one (building them
        # is the refinement's Python cost): frame id -> (keys, NonlinearFactorGraph of the
        # keyframe's factors in that order, {key: factor}), key = keypoint << 32 | track id;
        # valid for the noise settings in _projection_noise
        self._projections: dict[int, tuple] = {}
        self._projection_noise = None

    def copy_values(self):
        """A copy of the estimate (``gtsam.Values``)."""
        return self._gtsam.Values(self.values)

    def add_factors(self, graph) -> None:
        """Add the factors of a ``gtsam.NonlinearFactorGraph``."""
        for i in range(graph.size()):
            f = graph.at(i)
            self.factors.append((frozenset(f.keys()), f))

    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) current camera-to-world estimate of keyframe ``frame_id``, metres."""
        from gtsam.symbol_shorthand import X

        return self.values.atPose3(X(frame_id)).matrix()

    def set_pose(self, frame_id: int, T_w_c: np.ndarray) -> None:
        """Overwrite keyframe ``frame_id``'s estimate with ``T_w_c`` (4, 4)."""
        from gtsam.symbol_shorthand import X

        self.values.update(X(frame_id), self._gtsam.Pose3(T_w_c))

    def non_landmark_values(self, source=None):
        """Values of every non-landmark key (poses, motion-source keys) of ``source`` (default: the estimate)."""
        source = self.values if source is None else source
        keys = [k for k in source.keys() if self._gtsam.Symbol(k).chr() != ord("l")]
        return subset_values(source, keys)

    def marginalise(self, old_keys, keep: bool) -> None:
        """Marginalise the keys ``old_keys`` (:func:`~.marginalisation.marginalise_factors`) and
        drop their values. Raises :class:`~vio_core.errors.NumericalError` when it fails."""
        self.factors = marginalise_factors(self.factors, self.values, old_keys, keep)
        for k in old_keys:
            if self.values.exists(k):
                self.values.erase(k)

    def refine(self, cameras: dict[int, Camera], obs, mv: MultiviewPoints, use: np.ndarray, in_graph: np.ndarray,
               settings: LandmarkSettings) -> Refinement:
        """Levenberg-Marquardt over the estimate and the landmarks ``in_graph`` (module docstring).

        Args:
            cameras: the camera of each keyframe of the window, by frame id (window order).
            obs: the observations triangulated into ``mv`` (``TrackTable.observations``).
            mv: the multi-view triangulation at the current estimate.
            use: (M,) bool, the observations that become projection factors.
            in_graph: (T,) bool, the tracks that become landmarks (:func:`select_landmarks`).
            settings: the window's settings.
        """
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import L, X

        s = settings
        graph = gtsam.NonlinearFactorGraph()
        for _, f in self.factors:
            graph.add(f)
        values = self.non_landmark_values()
        rows = np.nonzero(in_graph)[0]
        landmark_keys = [L(tid) for tid in mv.track_ids[rows].tolist()]
        insert = values.insert
        for key, p in zip(landmark_keys, mv.points_w[rows]):
            insert(key, gtsam.Point3(p))
        pix = s.multiview.pixel_sigma_px
        idx = np.nonzero(use)[0]
        tids = mv.track_ids[mv.obs_track[idx]].astype(np.int64)
        noise = (float(pix), float(s.huber_sigmas))
        if noise != self._projection_noise or (len(tids) and tids.max() >= 1 << 32):  # (keys below: 32-bit ids)
            self._projections, self._projection_noise = {}, noise
        robust = None
        # one projection factor per used observation, in keyframe order; a factor of the last
        # refinement with the same keyframe, keypoint and track is reused (it is the same
        # factor: a keyframe's keypoints, camera and the noise model do not change) -- a
        # keyframe's whole list of them when it is unchanged --, the others are built, with the
        # keys and pixels converted per keyframe in bulk (~3 us per factor, all pybind: the
        # refinement's Python cost)
        factor = gtsam.GenericProjectionFactorCal3DS2
        frames = obs.frame[idx]
        kept: dict[int, tuple[list, object, dict[int, object]]] = {}
        for f, cam in cameras.items():
            sel = frames == f
            if not sel.any():
                continue
            keys = ((obs.keypoint[idx[sel]].astype(np.int64) << 32) | tids[sel]).tolist()
            old_keys, old_graph, old = self._projections.get(int(f), ([], None, {}))
            if keys == old_keys:  # the keyframe's factors of the last refinement, in the same order
                graph.push_back(old_graph)
                kept[int(f)] = (old_keys, old_graph, old)
                continue
            if robust is None:
                robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(s.huber_sigmas),
                                                        gtsam.noiseModel.Isotropic.Sigma(2, pix))
            uv, cal = projection_pixels(cam, obs.uv[idx[sel]])
            x = X(int(f))
            sub, new = gtsam.NonlinearFactorGraph(), {}
            add = sub.add
            for k, tid, p in zip(keys, tids[sel].tolist(), np.asarray(uv, float)):
                fac = old.get(k)
                if fac is None:
                    fac = factor(p, robust, x, L(tid), cal)
                add(fac)
                new[k] = fac
            graph.push_back(sub)
            kept[int(f)] = (keys, sub, new)
        self._projections = kept
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(s.lm_max_iterations)
        params.setAbsoluteErrorTol(s.lm_min_error_decrease)
        try:
            optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
            # the optimizer's own errors: graph.error at the start and at the result, computed once
            before = optimizer.error()
            result = optimizer.optimize()
            after = optimizer.error()
        except RuntimeError:  # indeterminant system: keep the previous estimate
            result = values
            before = after = graph.error(values)
        self.values = gtsam.Values(result)  # the estimate without the landmarks
        for key in landmark_keys:
            self.values.erase(key)
        try:
            marginals = gtsam.Marginals(graph, result)
            J = marginals.jointMarginalCovariance(gtsam.KeyVector([X(f) for f in cameras])).fullMatrix()
        except RuntimeError:  # no marginals (indeterminant): the caller keeps its covariance
            J = None
        return Refinement(int(use.sum()), float(before), float(after), J)
