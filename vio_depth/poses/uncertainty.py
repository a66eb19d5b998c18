"""What a pose source gets wrong: the stated uncertainty of the relative pose between two frames.

A two-view depth is only as good as the relative pose it is triangulated with: with a
1 cm baseline, a 0.1 degree rotation error at 1.5 m depth is a 26 % depth error. Every pose
source therefore states the covariance of the relative pose ``T_kf_cur`` it gives
(:attr:`RelativePose.covariance`, right perturbation ``T_kf_cur * Exp(xi)``, ``xi =
(rotation rad, translation m)`` in the current camera frame, as gtsam's ``Pose3``):

* ``imu`` from its preintegration covariance, ``vio`` from its marginal covariances;
* ``gt`` (a sequence's own poses) from a :class:`PoseUncertainty` preset of the kind of
  poses the sequence has (``Sequence.pose_kind``: rendered ``exact``, ``mocap``,
  ``kinectfusion``, ``ins``, ``headset``), chosen automatically or by name
  (``--pose-uncertainty``).

Model of one relative pose between frames ``k`` (keyframe) and ``c`` (current), each axis
independent::

    sigma_rot   = rotation_deg   + rotation_fraction    * |rotation of T_kf_cur|
    sigma_trans = translation_m  + translation_fraction * |translation of T_kf_cur|
    Sigma = diag(sigma_rot^2 I3, sigma_trans^2 I3)
            + time_jitter_s^2 * (z_c z_c^T + Ad z_k z_k^T Ad^T)

where ``z_c`` / ``z_k`` are the camera twists ``(omega rad/s, v m/s)`` of the two frames in
their own camera frames (a timestamp error ``dt`` moves a pose by ``dt * z``) and ``Ad``
the adjoint of ``T_cur_kf``. The pose sources estimate the twists from neighbouring poses
(:class:`FrameTwist`). The presets are starting points: where the images show that the
stated uncertainty is too small, the points stage inflates it online
(:mod:`triangulation.consistency`, docs/error_model.md).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array, check_transform
from vio_core.errors import SettingsError
from vio_core.geometry import adjoint, invert_transform, rotation_angle_deg
from vio_core.settings import Presets


@dataclass(frozen=True)
class PoseUncertainty:
    """1-sigma error of a relative pose given by a pose source (module docstring: the model).

    Attributes:
        rotation_deg: constant part of the rotation error, degrees per axis.
        rotation_fraction: part that grows with the relative rotation (fraction of its angle).
        translation_m: constant part of the translation error, metres per axis.
        translation_fraction: part that grows with the baseline (fraction of ``|t|``).
        time_jitter_s: 1-sigma error of each frame's timestamp against the poses' clock,
            seconds; turned into pose error through the camera's angular and linear
            velocity at that frame.
    """

    rotation_deg: float = 0.0
    rotation_fraction: float = 0.0
    translation_m: float = 0.0
    translation_fraction: float = 0.0
    time_jitter_s: float = 0.0

    def __post_init__(self):
        for name in ("rotation_deg", "rotation_fraction", "translation_m", "translation_fraction", "time_jitter_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SettingsError(f"PoseUncertainty.{name} must be finite and >= 0, got {v!r}")

    @property
    def exact(self) -> bool:
        """True when every term is zero (poses taken as exact: no covariance)."""
        return not any((self.rotation_deg, self.rotation_fraction, self.translation_m, self.translation_fraction,
                        self.time_jitter_s))

    def relative_covariance(self, T_kf_cur, twist_kf=None, twist_cur=None) -> np.ndarray:
        """(6, 6) covariance of the relative pose ``T_kf_cur`` (rotation rad, then translation m).

        Args:
            T_kf_cur: (4, 4) current-camera-to-keyframe-camera transform, metres.
            twist_kf / twist_cur: (6,) camera twist ``(omega rad/s, v m/s)`` of each frame in
                its own camera frame, or None (unknown: no timing term for that frame).
        """
        T = check_transform("T_kf_cur", T_kf_cur)
        s_rot = math.radians(self.rotation_deg) + self.rotation_fraction * math.radians(rotation_angle_deg(T[:3, :3]))
        s_trans = self.translation_m + self.translation_fraction * float(np.linalg.norm(T[:3, 3]))
        cov = np.diag([s_rot**2] * 3 + [s_trans**2] * 3)
        if self.time_jitter_s > 0:
            j2 = self.time_jitter_s**2
            if twist_cur is not None:
                z = check_array("twist_cur", twist_cur, (6,), finite=True)
                cov += j2 * np.outer(z, z)
            if twist_kf is not None:
                z = adjoint(invert_transform(T)) @ check_array("twist_kf", twist_kf, (6,), finite=True)
                cov += j2 * np.outer(z, z)
        return cov


#: Stated pose uncertainty per kind of poses (``Sequence.pose_kind``). Numbers are stated
#: guesses checked where we have data (docs/error_model.md, "Presets"):
#:
#: * ``exact``: rendered sequences (the bundled samples): no error, no covariance;
#: * ``mocap``: Vicon / OptiTrack marker bodies mapped to the camera (EuRoC, TUM RGB-D):
#:   0.1 deg and 2 mm + 1 %, 5 ms camera/mocap synchronisation;
#: * ``kinectfusion``: 7-Scenes: the poses track the depth camera, not the colour one, and
#:   the two are not synchronised: the colour points' error grows with the angular velocity
#:   (median 1.4 % below 10 deg/s, 3.6 % above, on Red Kitchen 0-299), which the 10 ms
#:   timing term models (docs/error_model.md); the images test and inflate it;
#: * ``ins``: KITTI OXTS RTK GPS/INS: 0.6 % median depth disagreement at a one-frame gap
#:   (LiDAR moved with these poses, ``../shared/data/README.md``);
#: * ``headset``: AR headset / phone VIO poses (ARKit, Quest): 0.2 deg, 5 mm + 1 %, 5 ms.
POSE_UNCERTAINTY_PRESETS: Presets = Presets("pose uncertainty preset", {
    "exact": PoseUncertainty(),
    "mocap": PoseUncertainty(rotation_deg=0.1, translation_m=0.002, translation_fraction=0.01, time_jitter_s=0.005),
    "kinectfusion": PoseUncertainty(rotation_deg=0.05, translation_m=0.002, translation_fraction=0.01,
                                    time_jitter_s=0.010),
    "ins": PoseUncertainty(rotation_deg=0.03, translation_m=0.01, translation_fraction=0.005),
    "headset": PoseUncertainty(rotation_deg=0.2, translation_m=0.005, translation_fraction=0.01,
                               time_jitter_s=0.005),
}, default="exact", descriptions={
    "exact": "rendered sequences: poses exact (no covariance)",
    "mocap": "motion capture mapped to the camera: 0.1 deg, 2 mm + 1 %, 5 ms sync",
    "kinectfusion": "7-Scenes KinectFusion (depth-camera) poses for the colour camera: 0.05 deg, 2 mm + 1 %, 10 ms",
    "ins": "RTK GPS/INS (KITTI OXTS): 0.03 deg, 1 cm + 0.5 %",
    "headset": "AR headset / phone VIO poses: 0.2 deg, 5 mm + 1 %, 5 ms",
})


def camera_twist(T_w_a, t_a: float, T_w_b, t_b: float) -> np.ndarray | None:
    """(6,) the camera twist ``(omega rad/s, v m/s)`` in frame ``a``'s camera frame, from the
    poses ``T_w_a``, ``T_w_b`` (4, 4) camera-to-world at ``t_a``, ``t_b`` seconds (finite
    differences: ``T_w_b = T_w_a Exp((t_b - t_a) z)`` to first order); None when the two
    timestamps coincide."""
    dt = float(t_b) - float(t_a)
    if not (abs(dt) > 1e-9 and math.isfinite(dt)):
        return None
    T_a_b = invert_transform(check_transform("T_w_a", T_w_a)) @ check_transform("T_w_b", T_w_b)
    omega = Rotation.from_matrix(T_a_b[:3, :3]).as_rotvec() / dt
    return np.r_[omega, T_a_b[:3, 3] / dt]


@dataclass
class _Seen:
    timestamp: float
    T_w_c: np.ndarray


class FrameTwist:
    """Camera twists of recently seen frames, from their neighbours' poses (bounded memory).

    A pose source calls :meth:`observe` with every frame it is given a pose of; :meth:`twist`
    is the finite difference with the nearest observed frame index (at most ``max_gap``
    frames away), so it works forwards, backwards (the offline backward pass) and with gaps.
    """

    def __init__(self, capacity: int = 256, max_gap: int = 3):
        self.capacity = capacity
        self.max_gap = max_gap
        self._seen: OrderedDict[int, _Seen] = OrderedDict()

    def observe(self, index: int, timestamp: float, T_w_c) -> None:
        if T_w_c is None or index in self._seen:
            return
        self._seen[index] = _Seen(float(timestamp), np.asarray(T_w_c, dtype=np.float64))
        while len(self._seen) > self.capacity:
            self._seen.popitem(last=False)

    def twist(self, index: int) -> np.ndarray | None:
        """(6,) twist of frame ``index`` in its camera frame, or None (no neighbour seen)."""
        me = self._seen.get(index)
        if me is None:
            return None
        for gap in range(1, self.max_gap + 1):
            for other in (index - gap, index + gap):
                o = self._seen.get(other)
                if o is not None:
                    z = camera_twist(me.T_w_c, me.timestamp, o.T_w_c, o.timestamp)
                    if z is not None:
                        return z
        return None
