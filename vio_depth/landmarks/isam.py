"""Incremental refinement of the landmark window with gtsam's iSAM2: :class:`IsamGraph`.

The window's ``LandmarkSettings.solver = "isam2"`` (the default since 2026-12-06; the
odometry's window keeps ``"batch"``, :class:`~.graph.WindowGraph`: Levenberg-Marquardt over
the whole window from scratch at every keyframe, then ``gtsam.Marginals``). :class:`IsamGraph`
has the same interface and keeps the factorisation between keyframes (``gtsam.ISAM2``, a Bayes tree): a keyframe's
update hands iSAM2 only what changed --

* the new keyframe's motion factors and initial values (and the marginal factors and gauge
  priors of a marginalisation);
* the projection factors of observations that entered the refinement (new keyframe, tracks
  extended or merged, landmarks newly selected by :func:`~.graph.select_landmarks`), with
  their landmark's triangulated point as its initial value when the landmark is new;
* the removal (``removeFactorIndices``) of projection factors no longer used (outliers
  detached from their track, landmarks no longer selected, the marginalised keyframe's),
  and of the marginalised keyframe's other factors;

and iSAM2 re-eliminates only the part of the Bayes tree those touch, relinearising the
variables that moved more than ``_RELINEARIZE_THRESHOLD`` (Gauss-Newton steps,
``_ITERATIONS`` per keyframe). A landmark left with fewer than two projection factors
leaves the graph (iSAM2 drops a variable without factors).

Marginalisation keeps the batch window's semantics exactly: the oldest keyframe's
projection factors are dropped and its other factors are eliminated into the same
``LinearContainerFactor`` (:func:`~.marginalisation.marginalise_factors`, at the current
estimate) -- which replaces them in iSAM2 (the old keys then have no factor and leave).

Differences from the batch solver: a landmark that stays in the graph keeps iSAM2's
estimate (it is not reset to its re-triangulation), and ``restart_from_priors`` does not
reset the poses (iSAM2 keeps its linearisation point; :meth:`set_pose` only moves keys not
yet in iSAM2). The keyframe poses' joint covariance comes from the Bayes tree
(``ISAM2.jointMarginalCovariance``). A gtsam failure inside the update (an indeterminant
system) rebuilds iSAM2 from the window's factors once, with QR instead of Cholesky from then on;
a second failure raises :class:`~vio_core.errors.NumericalError`.
"""

from __future__ import annotations

import logging

import numpy as np

from triangulation.multiview import MultiviewPoints
from vio_core.camera import Camera
from vio_core.errors import NumericalError

from .graph import Refinement, WindowGraph, projection_pixels
from .marginalisation import marginalise_factors
from .settings import LandmarkSettings

_log = logging.getLogger(__name__)

#: iSAM2 relinearises a variable whose linear step exceeds this (rad / m / m/s; gtsam's default 0.1):
#: 0.01 left the synthetic test scene's depths 11 % less accurate than the batch solver's (1.13 vs
#: 1.02 % median error; 0.001: 1.02 %)
_RELINEARIZE_THRESHOLD = 0.001
#: iSAM2 updates per keyframe: the one that adds the keyframe, then more Gauss-Newton steps. One: a
#: second update made a keyframe 30-50 % dearer (ASL sample 171 vs 94 ms CPU) for the same ATE
_ITERATIONS = 1


def _new_isam(qr: bool = False):
    """A fresh ``gtsam.ISAM2``: Cholesky, or QR (``qr``) for a window whose normal equations
    Cholesky found indeterminant."""
    import gtsam

    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(_RELINEARIZE_THRESHOLD)
    p.relinearizeSkip = 1
    p.evaluateNonlinearError = True
    p.findUnusedFactorSlots = True  # removed factors' slots are reused: memory stays bounded
    if qr:
        p.setFactorization("QR")
    return gtsam.ISAM2(p)


class IsamGraph(WindowGraph):
    """:class:`~.graph.WindowGraph` kept incrementally by iSAM2 (module docstring).

    ``values`` is the estimate of the non-landmark keys (poses, motion-source keys), the keys
    not yet in iSAM2 included; ``factors`` the non-visual factors held (as the batch graph's).
    """

    def __init__(self):
        super().__init__()
        self._isam = _new_isam()
        self._slot: dict[int, int] = {}  # id(non-visual factor) -> iSAM2 slot (absent: not added yet)
        # projection factors in iSAM2: (frame, keypoint, track id) -> (slot, factor)
        self._proj: dict[tuple[int, int, int], tuple[int, object]] = {}
        self._prior: dict[int, tuple[int, object]] = {}  # track id -> (slot, weak prior) of each landmark
        self._remove: list[int] = []  # slots to remove at the next update (marginalised keyframe's)
        self._noise = None
        self.factorization = "cholesky"  # "qr" after a failed update (see refine)
        self.updates = 0  # iSAM2 updates so far; rebuilds: from-scratch rebuilds after a failure
        self.rebuilds = 0

    def factor_slots(self) -> int:
        """Factors iSAM2 holds now (visual and non-visual; removed ones not counted)."""
        return len(self._slot) + len(self._proj) + len(self._prior)

    def marginalise(self, old_keys, keep: bool) -> None:
        """As the batch graph's (:func:`~.marginalisation.marginalise_factors`); the removal of
        the old factors and the addition of the marginal factors reach iSAM2 at the next update."""
        import gtsam

        old = set(old_keys)
        for k, f in self.factors:
            if k & old and id(f) in self._slot:
                self._remove.append(self._slot.pop(id(f)))
        # the marginal factors are new objects: no slot yet, added at the next update
        self.factors = marginalise_factors(self.factors, self.values, old_keys, keep)
        frames = {gtsam.Symbol(k).index() for k in old if gtsam.Symbol(k).chr() == ord("x")}
        for key in [k for k in self._proj if k[0] in frames]:
            self._remove.append(self._proj.pop(key)[0])
        for k in old_keys:
            if self.values.exists(k):
                self.values.erase(k)

    def refine(self, cameras: dict[int, Camera], obs, mv: MultiviewPoints, use: np.ndarray, in_graph: np.ndarray,
               settings: LandmarkSettings) -> Refinement:
        """One incremental iSAM2 update with the window's changes (module docstring); arguments
        as :meth:`~.graph.WindowGraph.refine`."""
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import X

        s = settings
        noise = (float(s.multiview.pixel_sigma_px), float(s.huber_sigmas))
        if self._noise is None:
            self._noise = noise
            self._robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(s.huber_sigmas),
                                                          gtsam.noiseModel.Isotropic.Sigma(2, noise[0]))
        elif noise != self._noise:
            raise NumericalError("landmarks: the iSAM2 window's projection noise cannot change")
        idx = np.nonzero(use & np.isin(obs.frame, list(cameras)))[0]
        row = mv.obs_track[idx]
        # a landmark needs two projection factors (one leaves its depth free)
        n_obs = np.bincount(row, minlength=len(mv.track_ids))
        idx = idx[n_obs[row] >= 2]
        tids = mv.track_ids[mv.obs_track[idx]].astype(np.int64)
        want = dict(zip(zip(obs.frame[idx].tolist(), obs.keypoint[idx].tolist(), tids.tolist()), idx.tolist()))
        newest = self.values.atPose3(X(next(reversed(cameras)))).translation()
        try:
            before, after = self._update(want, obs, mv, cameras, newest)
        except RuntimeError as exc:  # indeterminant system: rebuild from the window's factors
            _log.info("landmarks: iSAM2 update failed (%s): rebuilt from the window's factors", exc)
            self.rebuilds += 1
            # from then on QR: with the IMU factors' stiff camera-IMU mounting (1e-5) Cholesky found
            # the undamped Gauss-Newton system indeterminant at every keyframe after the VIO's start
            # on the street sample (it squares the condition number; the batch solver's
            # Levenberg-Marquardt damps it); QR costs 1.3-2x more per update
            self.factorization = "qr"
            self._isam, self._slot, self._proj, self._prior, self._remove = _new_isam(True), {}, {}, {}, []
            try:
                before, after = self._update(want, obs, mv, cameras, newest)
            except RuntimeError as exc2:
                raise NumericalError(f"landmarks: iSAM2 failed after a rebuild: {exc2}") from exc2
        estimate = self._isam.calculateEstimate()
        self.values = self.non_landmark_values(estimate)
        try:
            J = self._isam.jointMarginalCovariance([X(f) for f in cameras]).fullMatrix()
        except RuntimeError:
            J = None
        return Refinement(len(self._proj), float(before or 0.0), float(after or 0.0), J)

    # ------------------------------------------------------------------ helpers
    def _pose_keys_last(self):
        """iSAM2's ordering constraint: the non-landmark keys (poses, motion keys) are eliminated
        after the landmarks. Without it iSAM2 puts the keys of the new factors last -- every
        landmark the new keyframe sees -- and the Bayes tree's root becomes a dense block of
        them (synthetic scene, 500 landmarks: 1e6 non-zeros, 1-2 s per update)."""
        groups = self._gtsam.KeyGroupMap()
        for k in self.values.keys():
            groups.insert2(k, 1)
        return groups

    def _new_values(self):
        """The keys of ``values`` iSAM2 does not hold yet (the new keyframe's)."""
        gtsam = self._gtsam
        out = gtsam.Values(self.values)
        for k in list(out.keys()):
            if self._isam.valueExists(k):
                out.erase(k)
        return out

    def _projection_factors(self, keys, want, obs, cameras) -> list:
        """``GenericProjectionFactorCal3DS2`` of the observations ``keys`` (rows ``want[key]``)."""
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import L, X

        out = [None] * len(keys)
        frames = np.array([k[0] for k in keys], np.int64)
        rows = np.array([want[k] for k in keys], np.int64)
        for f, cam in cameras.items():
            sel = np.nonzero(frames == f)[0]
            if not len(sel):
                continue
            uv, cal = projection_pixels(cam, obs.uv[rows[sel]])
            x = X(int(f))
            for i, p in zip(sel.tolist(), np.asarray(uv, float)):
                out[i] = gtsam.GenericProjectionFactorCal3DS2(p, self._robust, x, L(keys[i][2]), cal)
        return out

    def _update(self, want, obs, mv, cameras, newest) -> tuple[float, float]:
        """Hand iSAM2 the changes that make its graph the window's with the projection factors
        ``want`` ({(frame, keypoint, track id): observation row}); ``(error before, after)``."""
        gtsam = self._gtsam
        from gtsam.symbol_shorthand import L

        wanted = {k[2] for k in want}
        remove = self._remove + [slot for k, (slot, _) in self._proj.items() if k not in want]
        remove += [slot for t, (slot, _) in self._prior.items() if t not in wanted]
        proj = {k: v for k, v in self._proj.items() if k in want}
        prior = {t: v for t, v in self._prior.items() if t in wanted}
        add = [k for k in want if k not in proj]
        graph = gtsam.NonlinearFactorGraph()
        pending = [f for _, f in self.factors if id(f) not in self._slot]
        new_factors = self._projection_factors(add, want, obs, cameras)
        # a new landmark: its triangulated point, and a weak prior there (sigma 10 x its distance
        # from the newest keyframe) that keeps a landmark of little parallax from making the
        # Gauss-Newton system indeterminant (the batch solver's Levenberg-Marquardt damps it)
        first = {}
        for k in add:
            if k[2] not in prior and k[2] not in first:
                first[k[2]] = mv.obs_track[want[k]]
        new_tids = list(first)
        pts = mv.points_w[list(first.values())] if first else np.zeros((0, 3))
        sig = 10.0 * np.maximum(np.linalg.norm(pts - newest, axis=1), 0.1)
        theta = self._new_values()
        priors = []
        for t, p, sg in zip(new_tids, pts, sig.tolist()):
            lk = L(t)
            if not self._isam.valueExists(lk):
                theta.insert(lk, gtsam.Point3(p))
            priors.append(gtsam.PriorFactorPoint3(lk, gtsam.Point3(p), gtsam.noiseModel.Isotropic.Sigma(3, sg)))
        for f in pending + new_factors + priors:
            graph.add(f)
        groups = self._pose_keys_last()
        result = self._isam.update(graph, theta, remove, groups)
        slots = list(result.getNewFactorsIndices())
        before = result.getErrorBefore()
        for _ in range(_ITERATIONS - 1):
            result = self._isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), [], groups)
        self.updates += _ITERATIONS
        n, m = len(pending), len(pending) + len(add)
        self._slot.update({id(f): slot for f, slot in zip(pending, slots[:n])})
        proj.update({k: (slot, f) for k, f, slot in zip(add, new_factors, slots[n:m])})
        prior.update({t: (slot, f) for t, f, slot in zip(new_tids, priors, slots[m:])})
        self._proj, self._prior, self._remove = proj, prior, []
        return before, result.getErrorAfter()
