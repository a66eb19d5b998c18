"""The odometry's side of the window contract: ImuFactors is a MotionFactorSource whose
initial states come as arguments (no state set from outside), an IMU gap is a failed
result with its reason (not an InputError), statuses and kinds are enums with the strings
the outputs always had, and the pair covariance is public."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError, ShapeError
from vio_depth.frame import ImuData
from vio_depth.landmarks import KeyframeInput, MotionFactorSource
from vio_depth.poses import FramePose, PoseStatus
from vio_depth.vio import VioSettings
from vio_depth.vio import ImuFactors, InitKind, KeyframeState, PoseHistory, VioStatus

gtsam = pytest.importorskip("gtsam")

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


def _resting_imu(t_end=1.0):
    t = np.arange(0.0, t_end, 0.005)
    return ImuData(t, np.zeros((len(t), 3)), np.tile([0.0, 0.0, 9.81], (len(t), 1)), np.eye(4))


def _kf(frame_id, t):
    return KeyframeInput(frame_id, t, CAM, None, np.zeros((0, 2)))


def test_imu_factors_keep_the_contract():
    src = ImuFactors(_resting_imu(), VioSettings())
    assert isinstance(src, MotionFactorSource) and src.provides_poses and src.keep_marginals
    start = KeyframeState(0.1, np.eye(4), np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="no initial state"):  # the first keyframe needs its state
        src.factors(None, _kf(0, 0.1), gtsam.Values())
    first = src.factors(None, _kf(0, 0.1), gtsam.Values(), initial=start)
    assert first.ok and first.graph.size() == 4 and len(src.extra_keys(0)) == 3
    estimate = gtsam.Values(first.initial)
    nxt = src.factors(_kf(0, 0.1), _kf(1, 0.5), estimate)  # predicted from keyframe 0: at rest
    assert nxt.ok
    from gtsam.symbol_shorthand import X

    assert np.allclose(nxt.initial.atPose3(X(1)).matrix(), np.eye(4), atol=1e-6)


def test_an_imu_gap_is_a_failed_result_with_its_reason():
    src = ImuFactors(_resting_imu(t_end=1.0), VioSettings())
    start = KeyframeState(0.1, np.eye(4), np.zeros(3), np.zeros(3), np.zeros(3))
    estimate = gtsam.Values(src.factors(None, _kf(0, 0.1), gtsam.Values(), initial=start).initial)
    out = src.factors(_kf(0, 0.1), _kf(1, 1.5), estimate)  # no samples after 1 s
    assert not out.ok and out.graph is None
    assert out.reason.startswith("vio: no IMU factor between keyframes 0 and 1: ")


def test_statuses_and_kinds_are_enums_with_the_same_strings():
    assert [k.value for k in InitKind] == ["static", "dynamic"] and InitKind.DYNAMIC == "dynamic"
    assert {s.value for s in VioStatus} <= {s.value for s in PoseStatus}
    assert {"retroactive", "unknown"} <= {s.value for s in PoseStatus}
    p = FramePose(None, ok=False, status=VioStatus.STILL.value)
    assert p.status is PoseStatus.STILL and json.dumps(p.status) == '"still"'
    assert FramePose(np.eye(4)).status is None and FramePose(np.eye(4), status="").status is None
    with pytest.raises(ValueError):
        FramePose(None, ok=False, status="wandering")


def test_the_pair_covariance_is_public_and_checked():
    T_a, T_b = np.eye(4), np.eye(4)
    T_b[:3, 3] = [1.0, 0.0, 0.0]
    S = np.diag(np.arange(1.0, 13.0)) * 1e-4
    C = PoseHistory.pair_covariance(T_a, T_b, S, 0, 1)
    assert C.shape == (6, 6) and np.allclose(C, C.T) and np.all(np.linalg.eigvalsh(C) > 0)
    # independent poses: the relative translation is at least as uncertain as either pose's
    assert np.all(np.diag(C)[3:] >= np.diag(S)[9:12] - 1e-15)
    with pytest.raises(ShapeError):
        PoseHistory.pair_covariance(T_a, T_b, S, 0, 2)


def test_a_kept_preintegration_predicts_from_updated_biases_like_a_new_one():
    """ImuFactors.predict_with (the bridges' reuse): a preintegration integrated at other
    biases, corrected by gtsam to first order, predicts within a small fraction of a fresh
    integration's motion; the same biases give the same prediction."""
    t = np.arange(0.0, 1.0, 0.005)
    gyro = np.column_stack([0.3 * np.sin(3 * t), 0.2 * np.cos(2 * t), 0.1 + 0 * t])
    accel = np.column_stack([np.sin(2 * t), 0.5 * np.cos(t), 9.81 + 0.3 * np.sin(4 * t)])
    src = ImuFactors(ImuData(t, gyro, accel, np.eye(4)), VioSettings())
    a = KeyframeState(0.1, np.eye(4), np.array([0.2, 0.0, 0.1]), np.zeros(3), np.zeros(3))
    b = KeyframeState(0.1, np.eye(4), a.velocity_w, np.array([0.02, -0.01, 0.03]), np.array([0.002, 0.001, -0.002]))
    pim, _ = src.preintegrate(a, 0.6)
    same, C_same, _ = src.predict_with(pim, a, 0.6)
    ref, C_ref, _ = src.predict(a, 0.6)
    np.testing.assert_allclose(same.T_w_i, ref.T_w_i, atol=1e-12)
    np.testing.assert_allclose(C_same, C_ref, atol=1e-15)
    kept, _, _ = src.predict_with(pim, b, 0.6)
    fresh, _, _ = src.predict(b, 0.6)
    moved = np.linalg.norm(fresh.T_w_i[:3, 3] - ref.T_w_i[:3, 3])
    assert moved > 1e-3  # the biases matter
    assert np.linalg.norm(kept.T_w_i[:3, 3] - fresh.T_w_i[:3, 3]) < 0.01 * moved
    np.testing.assert_allclose(kept.velocity_w, fresh.velocity_w, atol=1e-4)
