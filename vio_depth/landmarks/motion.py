"""The contract between the landmark window and whatever gives it its motion: :class:`MotionFactorSource`.

The window (:class:`~vio_depth.landmarks.window.LandmarkWindow`) owns the images'
factors (projections of the landmarks); a motion factor source owns everything else
about the keyframes' poses: for each new keyframe it returns the factors tying it to
the previous one (or anchoring the first) **and the initial values** of every key it
adds (:class:`MotionFactors`). The window calls it once per keyframe and at each
marginalisation; it never looks at the source's attributes beyond this Protocol.

Two sources implement it:

* :class:`PosePriorFactors` (the default: no odometry, poses from the pose source, as
  ``--points landmarks``): an absolute prior on every keyframe (or the first only) and a
  relative prior to the previous keyframe, from :class:`~.settings.PosePriorSettings`;
* :class:`vio_depth.vio.imu_factors.ImuFactors` (the odometry): IMU preintegration
  between keyframes, the initialisation's priors on the first one.

A failure that is an expected outcome of a frame (no IMU samples between two keyframes,
a prediction that is not finite) is not an exception: :meth:`MotionFactors.failed` with
the reason; the window then refuses the keyframe and is unchanged
(:attr:`~.types.WindowUpdate.status` ``refused``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vio_core.errors import InputError
from vio_core.geometry import invert_transform

from .settings import PosePriorSettings
from .types import KeyframeInput


@dataclass(frozen=True)
class MotionFactors:
    """What a :class:`MotionFactorSource` gives for one keyframe.

    Attributes:
        graph: ``gtsam.NonlinearFactorGraph`` of the new factors, or None when it failed.
        initial: ``gtsam.Values``: an initial value for every new key of the keyframe
            (always its pose ``X(frame_id)``; the source's extra keys), or None when it failed.
        reason: why it failed ("" when it did not).
    """

    graph: Any | None
    initial: Any | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.graph is not None and self.initial is not None

    @classmethod
    def failed(cls, reason: str) -> "MotionFactors":
        """No factors for this keyframe, because of ``reason`` (the keyframe is refused)."""
        return cls(None, None, reason)


@runtime_checkable
class MotionFactorSource(Protocol):
    """Gives the landmark window the motion of its keyframes (module docstring).

    Attributes:
        provides_poses: True when the source gives every keyframe's initial pose itself and
            the frames' pose priors are its own predictions in the window's current frame
            (the odometry): keyframes then enter the window without a sequence pose
            (``KeyframeInput.T_w_c`` None) and a frame's prior is used as it is by the
            query, not corrected the way its keyframe was. False: keyframes carry the pose
            source's poses, which the window corrects by its refinement.
        keep_marginals: True when the factors of a marginalised keyframe are eliminated into
            a linear marginal factor on the keys they share with the rest of the window (a
            chain of motion factors: dropping them would free the window); False when they
            are dropped (per-keyframe priors: every keyframe carries its own).
    """

    provides_poses: bool
    keep_marginals: bool

    def extra_keys(self, frame_id: int) -> list[int]:
        """gtsam keys the source adds for keyframe ``frame_id`` besides its pose ``X(frame_id)``
        (e.g. IMU pose, velocity, biases); they are marginalised together with it."""

    def factors(self, previous: KeyframeInput | None, current: KeyframeInput, estimate,
                initial: Any | None = None) -> MotionFactors:
        """Factors linking ``previous`` (None for the window's first keyframe) and ``current``,
        with initial values of every new key.

        Args:
            previous: the window's newest keyframe, or None.
            current: the new keyframe.
            estimate: the window's current ``gtsam.Values`` (read only).
            initial: the source's own initial state for ``current`` (e.g. the odometry's
                :class:`~vio_depth.vio.imu_factors.KeyframeState` from an initialisation),
                passed through unchanged by the window; None: the source predicts it.
        """

    def after_marginalisation(self, oldest: int, estimate):
        """``gtsam.NonlinearFactorGraph`` of factors to add on the window's new oldest keyframe
        ``oldest`` after a marginalisation (e.g. a gauge prior on the unobservable yaw and
        position of the odometry); an empty graph when there are none."""


def pose_noise(rot_sigma_rad: float, trans_sigma_m: float):
    """gtsam diagonal noise model of a pose: rotation sigma (rad) x3, then translation sigma (m) x3."""
    import gtsam

    return gtsam.noiseModel.Diagonal.Sigmas(np.array([rot_sigma_rad] * 3 + [trans_sigma_m] * 3))


class PosePriorFactors:
    """The default :class:`MotionFactorSource`: priors from the pose source's poses.

    Each keyframe with a pose ``T_w_c`` gets an absolute ``PriorFactorPose3`` (on every
    keyframe, or on the first only when ``absolute_on_every_keyframe`` is False -- which
    needs another source to carry the rest, so it is refused here) and a
    ``BetweenFactorPose3`` to the previous keyframe with the relative prior. Its initial
    value is its pose, corrected like the previous keyframe's (the previous keyframe's
    refined pose times the relative motion of the priors).

    Args:
        prior: :class:`PosePriorSettings` (resolved for the sequence's kind of poses).
    """

    provides_poses = False
    keep_marginals = False

    def __init__(self, prior: PosePriorSettings):
        if not prior.absolute_on_every_keyframe:
            raise InputError("landmarks: pose priors on the first keyframe only need a MotionFactorSource (IMU)")
        self.prior = prior

    def extra_keys(self, frame_id: int) -> list[int]:
        return []

    def factors(self, previous: KeyframeInput | None, current: KeyframeInput, estimate,
                initial: Any | None = None) -> MotionFactors:
        """The priors of ``current`` and its initial pose (class docstring); ``initial`` is not used."""
        import gtsam
        from gtsam.symbol_shorthand import X

        p = self.prior
        fid = int(current.frame_id)
        if current.T_w_c is None:
            raise InputError(f"landmarks: keyframe {fid} has no pose prior and no motion factor gave one")
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.PriorFactorPose3(X(fid), gtsam.Pose3(current.T_w_c),
                                         pose_noise(np.radians(p.absolute_rotation_deg), p.absolute_translation_m)))
        if previous is not None and previous.T_w_c is not None:
            T_rel = invert_transform(previous.T_w_c) @ current.T_w_c
            noise = gtsam.noiseModel.Diagonal.Sigmas(p.relative_sigmas(float(np.linalg.norm(T_rel[:3, 3]))))
            graph.add(gtsam.BetweenFactorPose3(X(previous.frame_id), X(fid), gtsam.Pose3(T_rel), noise))
        # initial value: the prior, corrected like the previous keyframe's
        T0 = current.T_w_c if previous is None or previous.T_w_c is None else (
            estimate.atPose3(X(previous.frame_id)).matrix() @ invert_transform(previous.T_w_c) @ current.T_w_c)
        values.insert(X(fid), gtsam.Pose3(T0))
        return MotionFactors(graph, values)

    def after_marginalisation(self, oldest: int, estimate):
        """No factors: every keyframe carries its own absolute prior."""
        import gtsam

        return gtsam.NonlinearFactorGraph()
