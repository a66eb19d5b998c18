"""LandmarkEstimator: pose-guided matching with the window's keyframes."""

from __future__ import annotations

import numpy as np
import pytest

from matchers import EpipolarPrior, GuidedSettings, PoseGuidedMatcher
from matchers.guided import band_half_widths
from vio_core.geometry import invert_transform
from vio_depth.landmarks import LandmarkEstimator, LandmarkSettings, PosePriorSettings

from .synthetic import IdMatcher, make_scene

gtsam = pytest.importorskip("gtsam")

ROT_DEG, TRANS_M = 0.1, 0.005  # the scene's per-pose prior errors, 1-sigma per axis
NOISY = PosePriorSettings(ROT_DEG, TRANS_M, ROT_DEG * 1.5, TRANS_M * 1.5, 0.0)


class RecordingGuidedMatcher(IdMatcher):
    """Matches by point id (perfectly) and records the pose prior of every pose-guided call."""

    def __init__(self):
        self.priors: list[tuple[EpipolarPrior, object, object]] = []
        self.plain_calls = 0

    def extract(self, image):
        raise NotImplementedError("the scene's features are given")

    def match(self, a, b):
        self.plain_calls += 1
        return super().match(a, b)

    def match_with_pose(self, a, b, prior: EpipolarPrior):
        self.priors.append((prior, a, b))
        return super().match(a, b)


def test_a_pose_guided_matcher_gets_each_keyframes_pose_and_a_band_that_holds_the_true_matches():
    scene = make_scene(n_frames=16, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M, seed=3)
    matcher = RecordingGuidedMatcher()
    assert isinstance(matcher, PoseGuidedMatcher)
    est = LandmarkEstimator(LandmarkSettings(pose_prior=NOISY), matcher)
    for k in range(len(scene.T_w_c)):
        est.process(k, k / 30.0, scene.camera, scene.T_prior[k], scene.features[k])
    # the window's keyframe matching went through match_with_pose only
    assert matcher.plain_calls == 0 and len(matcher.priors) >= 20
    a_to_frame = {id(f): k for k, f in enumerate(scene.features)}
    inside, rot_err, trans_err = [], [], []
    for prior, a, b in matcher.priors:
        ka, kb = a_to_frame[id(a)], a_to_frame[id(b)]
        T_true = invert_transform(scene.T_w_c[kb]) @ scene.T_w_c[ka]
        dT = invert_transform(T_true) @ prior.T_b_a
        rot_err.append(np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1) / 2, -1, 1))))
        trans_err.append(np.linalg.norm(dT[:3, 3]))
        assert prior.covariance is not None and np.all(np.linalg.eigvalsh(prior.covariance) > 0)
        # the true matches (same point id) against the band of a 3 px floor + 3 sigma, no floor
        # slack beyond the keypoints' 0.7 px noise
        ia, ib = a.descriptors[:, 0].astype(int), b.descriptors[:, 0].astype(int)
        _, pa, pb = np.intersect1d(ia, ib, return_indices=True)
        uv_a = scene.camera.undistort_points(a.keypoints[pa].astype(np.float64))
        uv_b = scene.camera.undistort_points(b.keypoints[pb].astype(np.float64))
        d, half = band_half_widths(prior, uv_a, uv_b, GuidedSettings(enabled=True))
        inside.append(np.mean(np.diag(d) <= np.diag(half)))
    # the priors are the frames' noisy ones corrected by the window: within a few sigmas of the truth
    assert np.median(rot_err) < 3 * ROT_DEG and np.median(trans_err) < 3 * np.sqrt(3) * TRANS_M * 1.5
    assert min(inside) > 0.99, f"true matches outside the band: {1 - min(inside):.3%} in the worst pair"


def test_the_guided_band_is_wider_for_an_older_keyframe_and_for_a_looser_prior():
    scene = make_scene(n_frames=12, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M, seed=4)
    est = LandmarkEstimator(LandmarkSettings(pose_prior=NOISY, max_keyframe_gap=2), IdMatcher())
    for k in range(10):
        est.process(k, k / 30.0, scene.camera, scene.T_prior[k], scene.features[k])
    w = est.window
    assert len(w.keyframe_ids) >= 3
    newest, older = w.keyframe_ids[-1], w.keyframe_ids[0]
    k = 10
    near, far = LandmarkEstimator.epipolar_priors(w, [newest, older], scene.camera, scene.T_prior[k])
    # an older keyframe is less certain relative to the newest: its pose adds to the frame's
    assert np.trace(far.covariance) > np.trace(near.covariance)
    (loose,) = LandmarkEstimator.epipolar_priors(w, [newest], scene.camera, scene.T_prior[k],
                                                 prior_covariance=100.0 * near.covariance)
    assert np.trace(loose.covariance) > 50 * np.trace(near.covariance)
    # the pose is the frame's prior in the keyframe's camera (the window barely moves it here)
    T = invert_transform(w.pose(newest)) @ scene.T_prior[k]
    assert np.allclose(near.T_b_a[:3, 3], T[:3, 3], atol=3 * TRANS_M)
