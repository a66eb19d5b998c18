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
