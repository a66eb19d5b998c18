"""IMU-only propagation error and covariance consistency (NEES) against ground-truth poses.

For every keyframe ``k`` (every ``stride`` frames) and window length ``W``, the
:class:`~vio_depth.poses.ImuPoseSource` predicts the relative camera pose from frame ``k`` to
the frame ``W`` seconds later (nearest frame), exactly as ``--poses imu`` does: the
keyframe's orientation is its ground-truth pose, its velocity and IMU biases come from
the ground-truth poses of the frames up to and including it (two-pose velocity, window
bias fit; see :mod:`vio_depth.poses.imu`), nothing after it. The prediction is compared with
the ground-truth relative pose:

* translation error ``|t_est - t_true|`` metres, also relative to the distance moved;
* rotation error: angle of ``R_est^T R_true``, degrees;
* NEES of the tangent error ``xi = Log(T_est^-1 T_true)`` (gtsam ``Pose3`` convention,
  rotation first, in the later camera frame) with the pose's (6, 6) covariance: the
  translation NEES ``xi_t^T C_tt^-1 xi_t`` and the rotation NEES ``xi_r^T C_rr^-1 xi_r``.
  Each is chi-square with 3 degrees of freedom when the covariance is consistent: mean 3,
  median 2.37, 95 % of the values below 7.81.

:func:`ground_truth_frames` turns a dense ground-truth table (EuRoC: 200 Hz) into
pixel-less frames at a camera rate, so that the whole IMU stream can be used although
images exist only for a few seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import SettingsError
from vio_core.geometry import invert_transform

from ..frame import Frame, ImuData
from ..io.tables import interpolate_poses
from ..poses import ImuPoseSettings, ImuPoseSource

#: 95 % quantile of chi-square with 3 degrees of freedom
CHI2_3DOF_95 = 7.814727903251178
#: median of chi-square with 3 degrees of freedom
CHI2_3DOF_MEDIAN = 2.365973884375338


class FrameList(list):
    """A list of frames that :class:`ImuPoseSource` can use as its sequence."""

    def __init__(self, frames, imu: ImuData, root: str = "frames"):
        super().__init__(frames)
        self.imu = imu
        self.root = root


def _no_image():
    raise RuntimeError("ground-truth frames carry no pixels")


def ground_truth_frames(t_gt, T_w_i_gt, T_c_i, camera: Camera, rate_hz: float, *, margin_s: float = 0.0) -> list[Frame]:
    """Pixel-less frames at ``rate_hz`` with camera poses interpolated from a dense table.

    Args:
        t_gt: (M,) seconds. T_w_i_gt: (M, 4, 4) IMU-to-world poses, metres (dense: the
            poses are interpolated linearly / along the geodesic, which at 200 Hz errs by
            micrometres).
        T_c_i: (4, 4) IMU-to-camera transform. camera: the frames' camera.
        rate_hz: frame rate. margin_s: seconds left out at both ends.
    """
    t_gt = check_array("t_gt", t_gt, (None,), finite=True)
    T = check_array("T_w_i_gt", T_w_i_gt, (len(t_gt), 4, 4), finite=True)
    t = np.arange(t_gt[0] + margin_s, t_gt[-1] - margin_s, 1.0 / rate_hz)
    T_w_i, ok = interpolate_poses(t, t_gt, T, 1.25 / rate_hz, bracketed_only=True)
    T_i_c = invert_transform(T_c_i)
    return [Frame(i, float(ti), f"{i:06d}", camera, Ti @ T_i_c, load_image=_no_image)
            for i, (ti, Ti) in enumerate(zip(t[ok], T_w_i[ok]))]


@dataclass(frozen=True)
class PropagationErrors:
    """Errors of the IMU-predicted relative poses of one window length.

    Attributes:
        window_s: nominal window, seconds. dt_s: (N,) actual intervals, seconds.
        translation_m: (N,) translation errors, metres. distance_m: (N,) true distances moved.
        rotation_deg: (N,) rotation errors, degrees.
        nees_translation, nees_rotation: (N,) NEES of the two 3-dof blocks.
    """

    window_s: float
    dt_s: np.ndarray
    translation_m: np.ndarray
    distance_m: np.ndarray
    rotation_deg: np.ndarray
    nees_translation: np.ndarray
    nees_rotation: np.ndarray

    def summary(self, min_distance_m: float = 0.05) -> dict:
        """Medians / p90s; relative errors only over intervals moving at least ``min_distance_m``."""
        moving = self.distance_m >= min_distance_m
        rel = self.translation_m[moving] / self.distance_m[moving]

        def q(x, p):
            return float(np.percentile(x, p)) if len(x) else float("nan")

        return {
            "window_s": self.window_s, "n": int(len(self.dt_s)), "n_moving": int(moving.sum()),
            "dt_s": q(self.dt_s, 50),
            "rel_translation_median": q(rel, 50), "rel_translation_p90": q(rel, 90),
            "translation_median_m": q(self.translation_m, 50),
            "rotation_median_deg": q(self.rotation_deg, 50), "rotation_p90_deg": q(self.rotation_deg, 90),
            "nees_translation_median": q(self.nees_translation, 50),
            "nees_translation_within_95": float(np.mean(self.nees_translation <= CHI2_3DOF_95)),
            "nees_rotation_median": q(self.nees_rotation, 50),
            "nees_rotation_within_95": float(np.mean(self.nees_rotation <= CHI2_3DOF_95)),
        }


def _pose_log(T) -> np.ndarray:
    """gtsam ``Pose3.Logmap`` of ``T: (4, 4)``: (rotation rad, translation m) tangent, 6 values."""
    import gtsam  # a core dependency (pyproject.toml)

    return np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(T)), float)


def evaluate_propagation(imu: ImuData, frames, windows_s=(0.25, 0.5, 1.0), *,
                         settings: ImuPoseSettings = ImuPoseSettings(), stride: int = 10,
                         first: int = 0) -> dict[float, PropagationErrors]:
    """Propagation errors and NEES of ``--poses imu`` over ``frames`` (posed, increasing time).

    Args:
        imu: the IMU samples (with ``T_c_i``).
        frames: frames with ground-truth ``T_w_c``; their poses feed the pose source's
            velocity and bias estimates (past frames only) and serve as the truth.
        windows_s: window lengths, seconds; each uses the frame nearest to ``W`` later.
        settings: pose-source settings (the covariance model under test).
        stride: keyframes every ``stride`` frames. first: index of the first keyframe.

    Returns:
        ``{window: PropagationErrors}``; refused intervals (``RelativePose.ok`` False) are left out.
    """
    frames = [f if f.index == i else replace(f, index=i) for i, f in enumerate(frames)]  # index = position
    if len(frames) < 2:
        raise SettingsError("need at least 2 frames")
    t = np.array([f.timestamp for f in frames])
    period = float(np.median(np.diff(t)))
    out = {}
    for W in windows_s:
        n = max(1, int(round(W / period)))
        source = ImuPoseSource(imu, FrameList(frames, imu), settings)  # fresh: no state shared between windows
        rows = []
        for k in range(first, len(frames) - n, stride):
            kf, cur = frames[k], frames[k + n]
            rel = source.relative(kf, cur)
            if not rel.ok:
                continue
            truth = invert_transform(kf.T_w_c) @ cur.T_w_c
            xi = _pose_log(invert_transform(rel.T_kf_cur) @ truth)
            C = rel.covariance
            rows.append((cur.timestamp - kf.timestamp, np.linalg.norm(rel.T_kf_cur[:3, 3] - truth[:3, 3]),
                         np.linalg.norm(truth[:3, 3]),
                         np.degrees(Rotation.from_matrix(rel.T_kf_cur[:3, :3].T @ truth[:3, :3]).magnitude()),
                         xi[3:] @ np.linalg.solve(C[3:, 3:], xi[3:]), xi[:3] @ np.linalg.solve(C[:3, :3], xi[:3])))
        a = np.array(rows, dtype=np.float64).reshape(-1, 6)
        out[W] = PropagationErrors(W, *(a[:, i].copy() for i in range(6)))
    return out


__all__ = ["CHI2_3DOF_95", "CHI2_3DOF_MEDIAN", "FrameList", "PropagationErrors", "evaluate_propagation",
           "ground_truth_frames"]
