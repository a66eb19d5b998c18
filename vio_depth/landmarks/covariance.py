"""Covariance bookkeeping of the window's keyframe poses: :class:`PoseCovariances`.

The window keeps the joint marginal covariance ``S`` (6K, 6K) of its K keyframe poses
(each block: right perturbation in the world, rotation rad first, then translation m),
oldest keyframe first. A new keyframe enters with the previous one's covariance plus the
relative prior's (:func:`prior_covariance`) until the refinement gives the true joint
marginal (:meth:`PoseCovariances.set`); a marginalised keyframe's rows and columns leave.
"""

from __future__ import annotations

import numpy as np

from vio_core.checks import check_array

from .settings import PosePriorSettings


def prior_covariance(prior: PosePriorSettings, translation_m: float) -> np.ndarray:
    """(6, 6) prior covariance of a pose relative to another ``translation_m`` metres away.

    The relative prior, or twice the absolute prior's variance where that is smaller (two
    independent absolute errors). Rotation rad^2 first, then translation m^2.
    """
    var = prior.relative_sigmas(translation_m) ** 2
    if prior.absolute_on_every_keyframe:
        a = np.array([np.radians(prior.absolute_rotation_deg)] * 3 + [prior.absolute_translation_m] * 3)
        var = np.minimum(var, 2.0 * a * a)
    return np.diag(var)


class PoseCovariances:
    """Joint covariance of the window's keyframe poses (module docstring)."""

    def __init__(self):
        self._ids: list[int] = []
        self._S = np.zeros((0, 0))

    @property
    def matrix(self) -> np.ndarray:
        """(6K, 6K) the joint covariance, keyframes oldest first (a copy)."""
        return self._S.copy()

    def append(self, frame_id: int, covariance: np.ndarray, relative: bool) -> None:
        """A new (newest) keyframe: ``covariance`` (6, 6) is its absolute covariance
        (``relative`` False, the first keyframe), or that of its pose relative to the
        previous newest keyframe, added to that keyframe's (and sharing its correlations)."""
        C = check_array("covariance", covariance, (6, 6))
        if relative and self._ids:
            self.append_relative_to(frame_id, C, self._ids[-1])
            return
        K = len(self._S)
        J = np.zeros((K + 6, K + 6))
        J[:K, :K] = self._S
        J[K:, K:] = C
        self._S = J
        self._ids.append(int(frame_id))

    def append_relative_to(self, frame_id: int, covariance: np.ndarray, reference: int) -> None:
        """A new (newest) keyframe whose ``covariance`` (6, 6) is that of its pose relative to
        keyframe ``reference`` (added to that keyframe's, sharing its correlations)."""
        C = check_array("covariance", covariance, (6, 6))
        K = len(self._S)
        r = 6 * self._ids.index(reference)
        J = np.zeros((K + 6, K + 6))
        J[:K, :K] = self._S
        J[K:, :K] = self._S[r:r + 6, :]
        J[:K, K:] = self._S[:, r:r + 6]
        J[K:, K:] = self._S[r:r + 6, r:r + 6] + C
        self._S = J
        self._ids.append(int(frame_id))

    def set(self, joint: np.ndarray) -> None:
        """Replace the joint covariance by ``joint`` (6K, 6K) (e.g. from ``gtsam.Marginals``), symmetrised."""
        J = check_array("joint", joint, (6 * len(self._ids), 6 * len(self._ids)))
        self._S = 0.5 * (J + J.T)

    def remove(self, frame_id: int) -> None:
        """Drop a (marginalised) keyframe's rows and columns."""
        i = 6 * self._ids.index(frame_id)
        keep = np.r_[0:i, i + 6:len(self._S)]
        self._S = self._S[np.ix_(keep, keep)]
        self._ids.remove(frame_id)

    def pose(self, frame_id: int) -> np.ndarray:
        """(6, 6) marginal covariance of a keyframe's pose in the world (rotation rad, translation m)."""
        i = 6 * self._ids.index(frame_id)
        return self._S[i:i + 6, i:i + 6].copy()

    def joint(self, frame_ids) -> np.ndarray:
        """(6K', 6K') joint marginal covariance of the keyframes ``frame_ids`` (in that order)."""
        ids = self._ids
        rows = np.concatenate([np.arange(6 * ids.index(f), 6 * ids.index(f) + 6) for f in frame_ids])
        return self._S[np.ix_(rows, rows)].copy()

    def relative(self, reference: int | None = None) -> np.ndarray:
        """(K, 6, 6) covariance of every keyframe pose given the ``reference`` keyframe's.

        The conditional covariance ``S_ii - S_ir S_rr^-1 S_ri`` of the joint marginal: how
        uncertain each pose is *relative to* the reference (default: the newest keyframe),
        which is what triangulation and depths depend on; the absolute (gauge) uncertainty
        shared by all poses cancels. The reference's own block is (numerically) zero.
        """
        ids = self._ids
        r = 6 * ids.index(ids[-1] if reference is None else reference)
        S = self._S
        S_rr = S[r:r + 6, r:r + 6] + 1e-15 * np.eye(6)
        S_xr = S[:, r:r + 6]
        cond = S - S_xr @ np.linalg.solve(S_rr, S_xr.T)
        cond = 0.5 * (cond + cond.T)
        blocks = np.stack([cond[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(len(ids))])
        return blocks + 1e-12 * np.eye(6)
