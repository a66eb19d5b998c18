"""The contract between the landmark window and its motion factor source: a source that
satisfies the Protocol drives the window (factors, initial values passed through, the
marginalisation hook), one that lacks a member is refused, a source with no factors for a
keyframe makes it a refused update (a status, the window unchanged), and a degenerate
graph raises NumericalError -- never InputError."""

from __future__ import annotations

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError, NumericalError, VioDepthError
from vio_core.geometry import invert_transform
from vio_depth.landmarks import (
    KeyframeInput,
    LandmarkEstimator,
    LandmarkSettings,
    LandmarkWindow,
    MotionFactors,
    MotionFactorSource,
    PosePriorFactors,
    UpdateStatus,
    marginalise_factors,
    pose_prior_preset,
)
from vio_depth.landmarks.motion import pose_noise

from .synthetic import IdMatcher, make_scene

gtsam = pytest.importorskip("gtsam")
from gtsam.symbol_shorthand import L, X  # noqa: E402

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


class _Between:
    """A complete MotionFactorSource: the first keyframe anchored at its pose, later ones tied
    to the previous by the true relative pose. Records what the window handed it."""

    provides_poses = False
    keep_marginals = True

    def __init__(self, T_w_c, fail_at=None):
        self.T_w_c = T_w_c
        self.fail_at = fail_at
        self.initial_seen: dict[int, object] = {}
        self.marginalised: list[int] = []

    def extra_keys(self, frame_id):
        return []

    def factors(self, previous, current, estimate, initial=None):
        f = current.frame_id
        self.initial_seen[f] = initial
        if f == self.fail_at:
            return MotionFactors.failed(f"no motion measured up to keyframe {f}")
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if previous is None:
            graph.add(gtsam.PriorFactorPose3(X(f), gtsam.Pose3(current.T_w_c), pose_noise(1e-3, 1e-3)))
            values.insert(X(f), gtsam.Pose3(current.T_w_c if initial is None else initial))
        else:
            rel = invert_transform(self.T_w_c[previous.frame_id]) @ self.T_w_c[f]
            graph.add(gtsam.BetweenFactorPose3(X(previous.frame_id), X(f), gtsam.Pose3(rel), pose_noise(1e-3, 2e-3)))
            values.insert(X(f), gtsam.Pose3(estimate.atPose3(X(previous.frame_id)).matrix() @ rel))
        return MotionFactors(graph, values)

    def after_marginalisation(self, oldest, estimate):
        self.marginalised.append(oldest)
        return gtsam.NonlinearFactorGraph()


class _NoHook(_Between):
    after_marginalisation = None  # a member missing: not a MotionFactorSource


class _NoCapabilities:
    def extra_keys(self, frame_id):
        return []

    def factors(self, previous, current, estimate, initial=None):
        return MotionFactors.failed("never")

    def after_marginalisation(self, oldest, estimate):
        return gtsam.NonlinearFactorGraph()


def _imu_settings(**kw):
    return LandmarkSettings(pose_prior=pose_prior_preset("imu"), **kw)


def test_a_source_satisfying_the_protocol_drives_the_window():
    scene = make_scene(n_frames=10, n_points=250, step_m=0.06, seed=21)
    src = _Between(scene.T_w_c)
    assert isinstance(src, MotionFactorSource)
    est = LandmarkEstimator(_imu_settings(window_keyframes=4, max_keyframe_gap=1), IdMatcher(), motion_factors=src)
    start = est.insert_keyframe(0, 0.0, scene.camera, scene.T_w_c[0], scene.features[0], (), initial=scene.T_w_c[0])
    assert start.ok and start.status == UpdateStatus.INSERTED
    errs = []
    for k in range(1, len(scene.T_w_c)):
        res = est.process(k, k / 30.0, scene.camera, scene.T_w_c[k], scene.features[k])
        if len(res.points) and k >= 5:  # once the window holds several keyframes
            z = scene.depth_of(k, scene.ids[k][res.points.keypoint_index])
            errs.append(np.abs(res.points.depth - z) / z)
    assert src.initial_seen[0] is not None  # passed through unchanged
    assert all(src.initial_seen[k] is None for k in src.initial_seen if k > 0)
    w = est.window
    assert w.keyframe_ids == list(range(6, 10)) and src.marginalised == [1, 2, 3, 4, 5, 6]
    assert np.median(np.concatenate(errs)) < 0.03
    # the window's landmarks in the world, for a points stage
    lm = w.world_landmarks()
    assert len(lm) > 100 and lm.points_w.shape == (len(lm), 3) and lm.covariance_w.shape == (len(lm), 3, 3)
    nearest = np.min(np.linalg.norm(lm.points_w[:, None] - scene.points_w[None], axis=2), axis=1)
    distance = np.linalg.norm(lm.points_w - w.pose(w.keyframe_ids[-1])[:3, 3], axis=1)
    assert np.median(nearest / distance) < 0.03  # as accurate as the depths above
    assert np.all(np.linalg.eigvalsh(lm.covariance_w) > -1e-12)


@pytest.mark.parametrize("source", [_NoHook, _NoCapabilities])
def test_a_source_missing_a_member_is_refused(source):
    obj = source(np.eye(4)[None]) if source is _NoHook else source()
    assert not isinstance(obj, MotionFactorSource)
    with pytest.raises(TypeError, match="not a MotionFactorSource"):
        LandmarkWindow(_imu_settings(), obj)


def test_the_default_source_implements_the_protocol():
    src = PosePriorFactors(pose_prior_preset("mocap"))
    assert isinstance(src, MotionFactorSource) and not src.provides_poses and not src.keep_marginals
    assert isinstance(LandmarkWindow(LandmarkSettings(pose_prior=pose_prior_preset("mocap"))).motion_factors,
                      PosePriorFactors)
    with pytest.raises(InputError):  # first-keyframe priors only: another source must carry the rest
        PosePriorFactors(pose_prior_preset("imu"))


def test_a_keyframe_without_motion_factors_is_refused_with_its_reason():
    scene = make_scene(n_frames=8, n_points=250, step_m=0.06, seed=22)
    src = _Between(scene.T_w_c, fail_at=5)
    est = LandmarkEstimator(_imu_settings(max_keyframe_gap=1), IdMatcher(), motion_factors=src)
    for k in range(5):
        assert est.process(k, k / 30.0, scene.camera, scene.T_w_c[k], scene.features[k]).keyframe
    w = est.window
    ids, factors = w.keyframe_ids, w.factor_count()
    res = est.process(5, 5 / 30.0, scene.camera, scene.T_w_c[5], scene.features[5])
    assert not res.keyframe and res.update is not None and not res.update.ok
    assert res.update.status == UpdateStatus.REFUSED and res.update.reason == "no motion measured up to keyframe 5"
    assert w.keyframe_ids == ids and w.factor_count() == factors and est.keyframe_features(5) is None
    # the window goes on with the next keyframe
    assert est.process(6, 6 / 30.0, scene.camera, scene.T_w_c[6], scene.features[6]).update.ok


def test_an_indeterminant_marginalisation_is_a_numerical_error():
    cal = gtsam.Cal3DS2(500.0, 500.0, 0.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0)
    f = gtsam.GenericProjectionFactorCal3DS2(np.array([320.0, 240.0]), gtsam.noiseModel.Isotropic.Sigma(2, 1.0),
                                             X(0), L(0), cal)
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(L(0), gtsam.Point3(0.0, 0.0, 5.0))
    with pytest.raises(NumericalError) as info:  # one projection cannot fix a 6-dof pose
        marginalise_factors([(frozenset(f.keys()), f)], values, [X(0)], keep=True)
    assert not isinstance(info.value, InputError) and isinstance(info.value, VioDepthError)
    # dropped (per-keyframe priors): nothing to eliminate, no error
    assert marginalise_factors([(frozenset(f.keys()), f)], values, [X(0)], keep=False) == []


class _Degenerate(_Between):
    """Adds to each keyframe an extra point key seen by one projection only: the window's
    graph cannot determine it, and eliminating it at marginalisation fails."""

    def extra_keys(self, frame_id):
        return [gtsam.symbol("q", frame_id)]

    def factors(self, previous, current, estimate, initial=None):
        out = super().factors(previous, current, estimate, initial)
        q = gtsam.symbol("q", current.frame_id)
        cal = gtsam.Cal3DS2(500.0, 500.0, 0.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0)
        out.graph.add(gtsam.GenericProjectionFactorCal3DS2(np.array([320.0, 240.0]),
                                                           gtsam.noiseModel.Isotropic.Sigma(2, 1.0),
                                                           X(current.frame_id), q, cal))
        T = out.initial.atPose3(X(current.frame_id)).matrix()
        out.initial.insert(q, gtsam.Point3(*(T[:3, :3] @ [0.0, 0.0, 5.0] + T[:3, 3])))
        return out


def test_a_degenerate_window_raises_numerical_error_not_input_error():
    """The batch window keeps its estimate while a refinement is indeterminate and raises when
    marginalising (keyframe 2); iSAM2 raises as soon as its update fails after a rebuild."""
    T = np.stack([np.eye(4)] * 4)
    T[:, 0, 3] = 0.05 * np.arange(4)
    w = LandmarkWindow(_imu_settings(window_keyframes=2, solver="batch"), _Degenerate(T))
    w.add_keyframe(KeyframeInput(0, 0.0, CAM, T[0], np.zeros((0, 2))))
    w.add_keyframe(KeyframeInput(1, 0.1, CAM, T[1], np.zeros((0, 2))))
    with pytest.raises(NumericalError):
        w.add_keyframe(KeyframeInput(2, 0.2, CAM, T[2], np.zeros((0, 2))))
    w = LandmarkWindow(_imu_settings(window_keyframes=2, solver="isam2"), _Degenerate(T))
    with pytest.raises(NumericalError):
        for k in range(3):
            w.add_keyframe(KeyframeInput(k, 0.1 * k, CAM, T[k], np.zeros((0, 2))))
