"""The two-view points stage hands the pair's known pose to a matcher that can use it
(pose-guided matching, :mod:`matchers.guided`), with the pose source's stated covariance."""

from __future__ import annotations

import numpy as np

from matchers import EpipolarPrior, Features, GuidedSettings, Matches, SiftMatcher, SiftSettings
from triangulation import TriangulationSettings
from vio_core import Camera
from vio_depth.frame import Frame
from vio_depth.keyframes import PAIRING_PRESETS
from vio_depth.pipeline import PipelineSettings, TwoViewPoints
from vio_depth.poses import GroundTruthPoses, GroundTruthPoseSettings

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


def _frame(index: int, x: float) -> Frame:
    T = np.eye(4)
    T[0, 3] = x
    return Frame(index, 0.1 * index, f"{index:06d}", CAM, T, load_image=lambda: np.zeros((480, 640, 3), np.uint8))


def _features(T_w_c, points_w, desc, rng) -> Features:
    p = (points_w - T_w_c[:3, 3]) @ T_w_c[:3, :3]
    uv = np.column_stack([CAM.fx * p[:, 0] / p[:, 2] + CAM.cx, CAM.fy * p[:, 1] / p[:, 2] + CAM.cy])
    uv += rng.normal(0, 0.2, uv.shape)
    d = desc + 0.02 * rng.random(desc.shape)
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return Features(uv.astype(np.float32), d, np.ones(len(uv), np.float32), (640, 480))


class _Recording(SiftMatcher):
    """SIFT matching that records the priors it is handed."""

    def __init__(self, settings):
        super().__init__(settings)
        self.priors: list[EpipolarPrior] = []

    def match_with_pose(self, feats_a, feats_b, prior) -> Matches:
        self.priors.append(prior)
        return super().match_with_pose(feats_a, feats_b, prior)


def _run(matcher, uncertainty: str):
    rng = np.random.default_rng(0)
    n = 300
    points = np.column_stack([rng.uniform(-6, 6, n), rng.uniform(-3, 3, n), rng.uniform(8, 20, n)])
    desc = rng.random((n, 128)) ** 4
    poses = GroundTruthPoses(GroundTruthPoseSettings(), pose_kind=uncertainty)
    stage = TwoViewPoints(matcher, poses, PAIRING_PRESETS["kitti"], TriangulationSettings(), min_matches=20)
    f0, f1 = _frame(0, 0.0), _frame(1, 2.0)
    stage.process(f0, _features(f0.T_w_c, points, desc, rng))
    return stage.process(f1, _features(f1.T_w_c, points, desc, rng))


def test_the_points_stage_passes_the_pose_and_its_covariance_to_the_matcher():
    guided = _Recording(SiftSettings(guided=GuidedSettings(enabled=True)))
    out = _run(guided, "ins")
    assert out.status == "ok" and len(out.depth) > 250
    (prior,) = guided.priors
    T_kf_cur = np.eye(4)
    T_kf_cur[0, 3] = 2.0  # the current camera 2 m along x of the keyframe
    np.testing.assert_allclose(prior.T_b_a, T_kf_cur, atol=1e-12)
    assert prior.covariance is not None and np.all(np.diag(prior.covariance) > 0)
    exact = _Recording(SiftSettings(guided=GuidedSettings(enabled=True)))
    _run(exact, "exact")
    assert exact.priors[0].covariance is None


def test_guided_points_equal_exhaustive_ones_on_a_clean_scene():
    off = _run(SiftMatcher(), "ins")
    on = _run(SiftMatcher(SiftSettings(guided=GuidedSettings(enabled=True))), "ins")
    assert len(on.depth) >= len(off.depth)
    common, i_on, i_off = np.intersect1d(on.uv[:, 0], off.uv[:, 0], return_indices=True)
    assert len(common) >= 0.95 * len(off.depth)
    np.testing.assert_allclose(on.depth[i_on], off.depth[i_off], rtol=1e-9)


def test_guided_matching_is_a_toml_setting():
    s = PipelineSettings.from_dict({"matcher": {"preset": "sift", "guided": {"enabled": True, "floor_px": 2.5}}})
    assert s.matcher.guided == GuidedSettings(enabled=True, floor_px=2.5)
    assert PipelineSettings.from_dict(s.to_dict()) == s
    assert PipelineSettings().matcher.guided.enabled is False  # off by default
