"""The stated uncertainty of a sequence's relative poses (issue 20, item 1)."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import SettingsError, UnknownNameError
from vio_core.geometry import invert_transform, make_transform, relative_transform
from vio_depth.frame import Frame
from vio_depth.poses import (
    POSE_UNCERTAINTY_PRESETS,
    FrameTwist,
    GroundTruthPoses,
    GroundTruthPoseSettings,
    PoseUncertainty,
    camera_twist,
)
from vio_core.camera import Camera


def _log(T):
    """(6,) rotation vector and translation of a small transform (first order)."""
    return np.r_[Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]]


def test_constant_and_proportional_terms():
    u = PoseUncertainty(rotation_deg=0.1, rotation_fraction=0.02, translation_m=0.002, translation_fraction=0.01)
    T = make_transform(Rotation.from_euler("y", 10, degrees=True).as_matrix(), [0.3, 0.0, 0.4])  # |t| = 0.5 m
    cov = u.relative_covariance(T)
    assert np.sqrt(cov[0, 0]) == pytest.approx(math.radians(0.1) + 0.02 * math.radians(10.0))
    assert np.sqrt(cov[3, 3]) == pytest.approx(0.002 + 0.01 * 0.5)
    assert np.allclose(cov, np.diag(np.diag(cov)))  # no timing term: independent axes


def test_time_jitter_matches_a_monte_carlo_of_shifted_timestamps():
    """A timestamp error dt moves each pose by dt * its twist: the stated covariance is what
    shifting both frames' times by independent N(0, jitter^2) errors does to T_kf_cur."""
    rng = np.random.default_rng(0)
    z_kf = np.array([0.3, -0.8, 0.2, 0.5, 0.1, 1.2])  # rad/s, m/s in each camera's frame
    z_cur = np.array([-0.6, 0.4, 0.1, 0.9, -0.2, 0.7])
    T_w_kf = make_transform(Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix(), [1.0, 2.0, 0.5])
    T_kf_cur = make_transform(Rotation.from_euler("xyz", [3, -8, 2], degrees=True).as_matrix(), [0.2, -0.1, 0.6])
    T_w_cur = T_w_kf @ T_kf_cur
    jitter = 0.01
    u = PoseUncertainty(time_jitter_s=jitter)
    cov = u.relative_covariance(T_kf_cur, z_kf, z_cur)

    def exp(z):
        return make_transform(Rotation.from_rotvec(z[:3]).as_matrix(), z[3:])

    xi = []
    for _ in range(4000):
        a, b = rng.normal(0, jitter, 2)
        T = relative_transform(T_w_kf @ exp(a * z_kf), T_w_cur @ exp(b * z_cur))
        xi.append(_log(invert_transform(T_kf_cur) @ T))  # right perturbation
    emp = np.cov(np.array(xi).T)
    assert np.allclose(emp, cov, atol=0.06 * np.abs(cov).max())
    # the preset names a kind of poses; exact has no covariance at all
    assert POSE_UNCERTAINTY_PRESETS["exact"].exact and not POSE_UNCERTAINTY_PRESETS["mocap"].exact


def test_validation_and_unknown_presets():
    with pytest.raises(SettingsError, match="rotation_deg"):
        PoseUncertainty(rotation_deg=-0.1)
    with pytest.raises(SettingsError, match="time_jitter_s"):
        PoseUncertainty(time_jitter_s=float("inf"))
    with pytest.raises(UnknownNameError, match="kinectfusion"):
        POSE_UNCERTAINTY_PRESETS["vicon-ish"]
    assert set(POSE_UNCERTAINTY_PRESETS) >= {"exact", "mocap", "kinectfusion", "ins", "headset"}


def test_twists_from_neighbouring_poses_forwards_and_backwards():
    z = np.array([0.2, -0.5, 0.1, 1.0, 0.0, 2.0])
    poses = [make_transform(Rotation.from_rotvec(z[:3] * t).as_matrix(), z[3:] * t) for t in (0.0, 0.1, 0.2)]
    # a constant body twist: T(t) = Exp(t z) up to first order in the rotation's coupling
    tw = FrameTwist()
    tw.observe(5, 0.1, poses[1])
    assert tw.twist(5) is None  # no neighbour yet
    tw.observe(4, 0.0, poses[0])
    assert np.allclose(tw.twist(5)[:3], z[:3], atol=1e-9)  # backwards difference
    assert np.allclose(camera_twist(poses[0], 0.0, poses[2], 0.2)[:3], z[:3])
    assert camera_twist(poses[0], 1.0, poses[1], 1.0) is None  # same timestamp


def _frame(i, t, T):
    return Frame(index=i, stem=f"{i:06d}", timestamp=t, camera=Camera(64, 48, 50, 50, 32, 24),
                 load_image=lambda: np.zeros((48, 64, 3), np.uint8), T_w_c=T)


def test_ground_truth_source_states_its_kind_of_poses():
    T0 = np.eye(4)
    T1 = make_transform(np.eye(3), [0.05, 0.0, 0.0])
    a, b = _frame(0, 0.0, T0), _frame(1, 0.05, T1)
    assert GroundTruthPoses().relative(a, b).covariance is None  # exact (rendered) by default
    assert GroundTruthPoses(pose_kind="exact").relative(a, b).covariance is None
    rel = GroundTruthPoses(pose_kind="mocap").relative(a, b)
    m = POSE_UNCERTAINTY_PRESETS["mocap"]
    assert np.sqrt(rel.covariance[0, 0]) >= math.radians(m.rotation_deg)
    # an explicit uncertainty wins over the sequence's kind
    own = PoseUncertainty(rotation_deg=1.0)
    rel = GroundTruthPoses(GroundTruthPoseSettings(uncertainty=own), pose_kind="mocap").relative(a, b)
    assert np.sqrt(rel.covariance[0, 0]) == pytest.approx(math.radians(1.0))
