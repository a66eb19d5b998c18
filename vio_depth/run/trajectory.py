"""The camera trajectory a run used (``trajectory.tum``) and its error against ground-truth poses.

The pipeline only uses relative poses: for each frame, ``T_kf_cur`` from the pose source to
its first partner keyframe (the newest qualifying one; a later keyframe in the offline
backfill). The run's pose of a frame applies that relative pose to the keyframe's pose --
the sequence's pose of the keyframe when it has one (where both pose sources anchor), else
the run's own pose of the keyframe (chained; without any sequence pose the first frame is
the origin)::

    T_w_cur = T_w_kf T_kf_cur

With ``--points landmarks`` a frame's pose is the landmark window's refined pose of it
(the sequence's pose corrected by the images within its prior). With ``--poses gt`` and
two-view points this reproduces the sequence's poses (ATE ~ 0, a consistency check);
with ``--poses imu`` on a posed sequence each pose is the IMU prediction from its keyframe,
so ATE and RPE measure the poses the triangulation used. Frames without a relative pose
(the first frame, ``no_pose``) get no line.

A tracking pose source (``--poses vio``) has its own world poses: then the trajectory is
the source's latest pose of each frame it posed (``world_poses``, read at the end of the
run: for the odometry, each frame relative to its keyframe as last estimated by the
fixed-lag smoother, the frames of its initialisation included), never a sequence pose.

When the sequence has poses (its ground truth), :func:`run_trajectory` also gives the ATE
(SE(3)-aligned, no scale correction) and the RPE over ``rpe_delta_m`` metres of path, with
the definitions of :mod:`vio_depth.evaluation.trajectory`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.errors import InputError

from ..evaluation import AteResult, CameraTrajectory, RpeResult, absolute_trajectory_error, relative_pose_error
from ..io import Sequence
from ..pipeline import FrameResult


@dataclass(frozen=True)
class TrajectoryReport:
    """The run's camera trajectory and, with ground-truth poses, its errors.

    Attributes:
        trajectory: the poses used (camera-to-world, one per frame with a relative pose).
        reference_poses: frames with a sequence (ground-truth) pose.
        ate: ATE against them, or None. rpe: RPE over ``rpe_delta_m`` metres, or None.
        note: why ATE or RPE is missing ("" when both are there).
    """

    trajectory: CameraTrajectory
    reference_poses: int
    ate: AteResult | None = None
    rpe: RpeResult | None = None
    note: str = ""

    def to_json(self) -> dict:
        return {"poses": len(self.trajectory), "reference_poses": self.reference_poses,
                "ate": None if self.ate is None else self.ate.to_json(),
                "rpe": None if self.rpe is None else self.rpe.to_json(), "note": self.note}


@dataclass(frozen=True)
class PosedFrame:
    """What the trajectory needs of one frame's result (a run keeps only this of each frame).

    Attributes:
        T_w_c: (4, 4) camera-to-world pose the points stage used (the landmark window's), or None.
        relative_pose: ``(keyframe index, T_kf_cur (4, 4))`` of its first pair, or None.
    """

    T_w_c: np.ndarray | None
    relative_pose: tuple[int, np.ndarray] | None

    @classmethod
    def of(cls, result: FrameResult) -> "PosedFrame":
        return cls(result.points.T_w_c, result.points.relative_pose)


def used_poses(sequence: Sequence, results: dict[int, FrameResult | PosedFrame],
               world_poses: dict[int, np.ndarray | None] | None = None) -> CameraTrajectory:
    """The camera-to-world poses the run's relative poses imply, or, given ``world_poses``
    (frame index -> (4, 4) or None: a tracking pose source's own poses), those (see the
    module docstring). ``results``: each frame's result, or just its :class:`PosedFrame`."""
    results = {i: r if isinstance(r, PosedFrame) else PosedFrame.of(r) for i, r in results.items()}
    if world_poses is not None:
        keep = sorted(i for i in results if world_poses.get(i) is not None)
        return CameraTrajectory(np.array([sequence[i].timestamp for i in keep], dtype=np.float64),
                                np.stack([world_poses[i] for i in keep]) if keep else np.zeros((0, 4, 4)))
    frames = {i: sequence[i] for i in results}
    poses: dict[int, np.ndarray] = {}
    origin = min(results, default=0)

    def anchor(k: int) -> np.ndarray | None:
        if k in frames and frames[k].T_w_c is not None:
            return np.asarray(frames[k].T_w_c, dtype=np.float64)
        if k in poses:
            return poses[k]
        if k == origin and not any(f.T_w_c is not None for f in frames.values()):
            return np.eye(4)
        return None

    # a stage that used world poses (the landmark window's refined poses) gives them directly
    poses.update({i: np.asarray(r.T_w_c, dtype=np.float64) for i, r in results.items() if r.T_w_c is not None})
    pairs = {i: r.relative_pose for i, r in results.items() if r.relative_pose is not None and i not in poses}
    # forward pairs in time order, then backfill pairs (with later keyframes) backwards in time
    order = sorted(i for i, (k, _) in pairs.items() if k < i) + sorted((i for i, (k, _) in pairs.items() if k > i),
                                                                       reverse=True)
    for i in order:
        k, T_kf_cur = pairs[i]
        T_w_kf = anchor(k)
        if T_w_kf is not None:
            poses[i] = T_w_kf @ T_kf_cur
    keep = sorted(poses)
    return CameraTrajectory(np.array([frames[i].timestamp for i in keep], dtype=np.float64),
                            np.stack([poses[i] for i in keep]) if keep else np.zeros((0, 4, 4)))


def run_trajectory(sequence: Sequence, results: dict[int, FrameResult | PosedFrame], rpe_delta_m: float,
                   world_poses: dict[int, np.ndarray | None] | None = None) -> TrajectoryReport:
    """The run's trajectory, with ATE and RPE against the sequence's poses when it has them
    (``world_poses``: a tracking pose source's own poses, see :func:`used_poses`)."""
    est = used_poses(sequence, results, world_poses)
    ref = CameraTrajectory.from_optional_poses(np.array([sequence[i].timestamp for i in sorted(results)]),
                                               [sequence[i].T_w_c for i in sorted(results)])
    if len(ref) == 0:
        return TrajectoryReport(est, 0, note="the sequence has no poses: no ATE / RPE")
    try:
        ate = absolute_trajectory_error(est, ref)
    except InputError as exc:
        return TrajectoryReport(est, len(ref), note=f"no ATE / RPE: {exc}")
    rpe = relative_pose_error(est, ref, rpe_delta_m)
    if rpe.translation.n == 0:
        return TrajectoryReport(est, len(ref), ate, note=f"no RPE: the path is shorter than {rpe_delta_m} m")
    return TrajectoryReport(est, len(ref), ate, rpe)
