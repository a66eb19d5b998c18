"""Tests of vio_depth/baselines/paper_reference.py: the published code's choices, step by step and end to end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import MissingDependencyError, SettingsError, UnknownNameError
from vio_core.geometry import make_transform
from vio_depth.baselines.paper_reference import (
    PAPER_REFERENCE_PRESETS,
    PaperReferenceSettings,
    PaperReferenceStatus,
    choose_partner,
    fit_sklearn_ransac,
    flann_nearest,
    paper_reference_preset,
    published_depth,
    published_gray,
    run_paper_reference,
    sample_disparity,
    sequence_poses,
    sift_features,
    triangulate_unchecked,
)

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"


def _line_poses(steps_m, yaw_deg=None):
    """(N, 4, 4) poses moving along +z by ``steps_m`` per frame (and yawing by ``yaw_deg``)."""
    z = np.concatenate([[0.0], np.cumsum(steps_m)])
    yaw = np.zeros_like(z) if yaw_deg is None else np.concatenate([[0.0], np.cumsum(yaw_deg)])
    return np.stack([make_transform(Rotation.from_euler("y", a, degrees=True).as_matrix(), [0.0, 0.0, zz])
                     for zz, a in zip(z, yaw)])


def test_choose_partner_takes_the_newest_qualifying_earlier_frame():
    poses = _line_poses([0.6] * 9)  # frame k at z = 0.6 k
    s = PaperReferenceSettings(min_translation_m=1.5)
    # frame 5 (z = 3.0): frames 3 (1.2 m) and 4 (0.6 m) do not qualify, frame 2 (1.8 m) does
    assert choose_partner(poses, 5, s) == 2
    assert choose_partner(poses, 2, s) is None  # 1.2 m to frame 0: below the threshold
    assert choose_partner(poses, 3, s) == 0


def test_choose_partner_published_lookback_only_tries_the_previous_frame():
    poses = _line_poses([0.6, 2.0, 0.6, 0.6])
    s = paper_reference_preset("published_kitti")
    assert s.max_lookback == 1
    assert choose_partner(poses, 2, s) == 1  # 2.0 m from the previous frame
    assert choose_partner(poses, 3, s) is None  # previous frame 0.6 m away: dropped, no search back
    assert choose_partner(poses, 4, s) is None
    assert choose_partner(poses, 4, paper_reference_preset("kitti")) == 1  # the default searches back


def test_choose_partner_rotation_alone_qualifies_and_missing_poses_are_skipped():
    poses = _line_poses([0.01, 0.01, 0.01], yaw_deg=[6.0, 1.0, 1.0])
    s = PaperReferenceSettings()
    assert choose_partner(poses, 1, s) == 0  # 6 degrees, 1 cm
    assert choose_partner(poses, 3, s) == 0  # 2 degrees to frame 1 and 2: not enough
    poses[0] = np.nan
    assert choose_partner(poses, 3, s) is None
    assert choose_partner(poses, 0, s) is None


def test_settings_and_presets_reject_bad_values():
    with pytest.raises(SettingsError):
        PaperReferenceSettings(max_lookback=0)
    with pytest.raises(SettingsError):
        PaperReferenceSettings(min_translation_m=0.0)
    with pytest.raises(UnknownNameError, match="kitti"):
        paper_reference_preset("nope")
    assert PAPER_REFERENCE_PRESETS["ddad"].min_translation_m == 2.0


def test_flann_matches_every_query_without_ratio_test_and_is_seeded():
    rng = np.random.default_rng(0)
    train = rng.random((200, 128)).astype(np.float32)
    train[1] = train[0]  # an exact duplicate: distance ratio 1, any ratio test would reject it
    query = train[:50] + rng.normal(0, 1e-3, (50, 128)).astype(np.float32)
    query = np.vstack([query, rng.random((30, 128)).astype(np.float32)])  # 30 with no true partner
    nn = flann_nearest(query, train, seed=3)
    assert nn.shape == (80,)  # every query descriptor gets a match, also the 30 without a partner
    assert nn[0] in (0, 1)
    assert np.mean(nn[2:50] == np.arange(2, 50)) > 0.9
    assert np.array_equal(nn, flann_nearest(query, train, seed=3))


def test_triangulation_has_no_checks():
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    T_partner_cur = make_transform(np.eye(3), [-1.0, 0.0, 0.0])  # partner 1 m to the right
    pts = np.array([[0.5, 0.2, 10.0], [-2.0, 1.0, 30.0], [0.3, -0.4, -5.0]])  # the last is behind
    p_par = pts @ T_partner_cur[:3, :3].T + T_partner_cur[:3, 3]

    def proj(p):
        return np.stack([500 * p[:, 0] / p[:, 2] + 320, 500 * p[:, 1] / p[:, 2] + 240], 1)

    out = triangulate_unchecked(proj(pts), proj(p_par), cam, T_partner_cur)
    np.testing.assert_allclose(out, pts, rtol=1e-6, atol=1e-6)  # behind-camera point kept


def test_sklearn_fit_recovers_affine_with_outliers_and_is_seeded():
    rng = np.random.default_rng(1)
    d = rng.uniform(0.1, 1.0, 300)
    alpha, beta = 0.2, 0.01
    m = alpha * d + beta
    m[:60] = rng.uniform(0.5 * m.min(), 1.5 * m.max(), 60)  # 20 % outliers
    fit = fit_sklearn_ransac(d, 1.0 / m, seed=5)
    # the default threshold (MAD of the targets) also admits the outliers near the line, so the
    # final least squares is close to, not exactly on, the truth
    assert fit.alpha == pytest.approx(alpha, rel=0.02) and fit.beta == pytest.approx(beta, abs=2e-3)
    assert fit.inliers[60:].all() and fit.inliers[:60].mean() < 0.5
    again = fit_sklearn_ransac(d, 1.0 / m, seed=5)
    assert (again.alpha, again.beta) == (fit.alpha, fit.beta)


def test_published_depth_mirrors_negative_metric_disparity():
    d = np.array([[1.0, -1.0, np.nan]], np.float32)
    depth = published_depth(d, 0.1, -0.05)  # alpha d + beta = 0.05, -0.15, NaN
    np.testing.assert_allclose(depth[0, :2], [1 / 0.051, 1 / 0.151], rtol=1e-6)
    assert np.isnan(depth[0, 2])


def test_gray_and_sampling_follow_the_published_code():
    img = np.zeros((4, 5, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 200, 100, 50
    assert published_gray(img)[0, 0] == int(0.2125 * 200 + 0.7154 * 100 + 0.0721 * 50)
    disp = np.arange(20, dtype=np.float32).reshape(4, 5)
    np.testing.assert_allclose(sample_disparity(disp, [[1.5, 2.0], [0.0, 0.5]]), [11.5, 2.5])


@pytest.fixture(scope="module")
def street():
    from vio_depth.io import open_sequence

    return open_sequence(STREET)


def test_street_slice_end_to_end(street):
    """Frames 0-11 of the street sample (SIMULATED disparity): first frames dropped, the rest
    paired by the paper's rule, every keypoint matched, metric depth close to the ground truth."""
    settings = paper_reference_preset("kitti")
    frames = list(range(12))
    results = run_paper_reference(street, settings=settings, frames=frames)
    poses = sequence_poses(street)
    assert [r.frame for r in results] == frames
    dropped = [r for r in results if not r.has_depth]
    assert all(r.status is PaperReferenceStatus.NO_PAIR and r.depth is None for r in dropped)
    assert [r.frame for r in dropped] == [r.frame for r in results[: len(dropped)]]  # only the first ones
    assert 1 <= len(dropped) <= 4
    for r in results[len(dropped):]:
        assert r.status is PaperReferenceStatus.OK, r.reason
        assert r.partner == choose_partner(poses, r.frame, settings) is not None
        assert r.matches == len(sift_features(street.frame(r.frame).image())[0])  # no ratio test
        assert r.points <= r.matches and r.inliers <= r.points
        gt = street.frame(r.frame).gt_depth()
        ok = (gt > 0) & (gt < 80)
        rel = np.abs(r.depth[ok] - gt[ok]) / gt[ok]
        assert np.median(rel) < 0.1
    again = run_paper_reference(street, settings=settings, frames=frames[-3:])
    assert [(r.alpha, r.beta) for r in again] == [(r.alpha, r.beta) for r in results[-3:]]


def test_published_pairing_drops_every_street_frame(street):
    """Street moves 0.4-0.8 m and < 3.5 degrees per frame: the published previous-frame rule finds no pair."""
    results = run_paper_reference(street, settings=paper_reference_preset("published_kitti"), frames=range(6))
    assert all(r.status is PaperReferenceStatus.NO_PAIR and r.depth is None for r in results)


def test_missing_scikit_learn_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "sklearn", None)  # `import sklearn...` now raises ImportError
    monkeypatch.setitem(sys.modules, "sklearn.linear_model", None)
    with pytest.raises(MissingDependencyError, match=r"scikit-learn.*\[baselines\]"):
        fit_sklearn_ransac(np.linspace(0.1, 1, 20), np.linspace(1, 10, 20), seed=0)
