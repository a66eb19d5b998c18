"""SIFT matcher: correctness on a real textured photo warped by a known homography,
the effect of the ratio/mutual checks, extract-once, edge cases and KITTI (if present)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
skdata = pytest.importorskip("skimage.data")

from matchers import Matcher, Matches, create_matcher  # noqa: E402
from matchers.sift import SiftMatcher, SiftSettings, nearest_two, normalize_descriptors, ratio_match  # noqa: E402
from vio_core.errors import SettingsError, ShapeError  # noqa: E402

# rotation 0.2 rad, scale 0.9, shift, mild perspective
H_TRUE = np.array([[0.9 * np.cos(0.2), -0.9 * np.sin(0.2), 60.0],
                   [0.9 * np.sin(0.2), 0.9 * np.cos(0.2), -20.0],
                   [2e-4, 1e-4, 1.0]])
CORRECT_PX = 2.0  # a match is correct when within 2 px of the true warp

KITTI_DRIVE = (Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti_tiny"
               / "2011_09_26" / "2011_09_26_drive_0023_sync")


@pytest.fixture(scope="module")
def astronaut_pair():
    img = skdata.astronaut()  # (512, 512, 3) uint8 RGB
    warped = cv2.warpPerspective(img, H_TRUE, (img.shape[1], img.shape[0]))
    return img, warped


@pytest.fixture(scope="module")
def astronaut_features(astronaut_pair):
    m = SiftMatcher()
    return m.extract(astronaut_pair[0]), m.extract(astronaut_pair[1])


def _match_errors(fa, fb, matches):
    pa = fa.keypoints[matches.idx_a].astype(np.float64).reshape(-1, 1, 2)
    pw = cv2.perspectiveTransform(pa, H_TRUE).reshape(-1, 2)
    return np.linalg.norm(pw - fb.keypoints[matches.idx_b], axis=1)


def test_features_are_well_formed(astronaut_pair, astronaut_features):
    fa, _ = astronaut_features
    h, w = astronaut_pair[0].shape[:2]
    assert 300 < len(fa) <= SiftSettings().max_features
    assert fa.keypoints.dtype == np.float32 and fa.descriptors.dtype == np.float32
    assert fa.descriptors.shape == (len(fa), 128)
    assert fa.image_size == (w, h)
    assert np.all((fa.keypoints >= -0.5) & (fa.keypoints <= [w - 0.5, h - 0.5]))
    # RootSIFT: non-negative and unit L2 norm
    assert np.all(fa.descriptors >= 0)
    np.testing.assert_allclose(np.linalg.norm(fa.descriptors, axis=1), 1.0, atol=1e-5)


def test_matches_follow_the_true_homography(astronaut_features):
    fa, fb = astronaut_features
    m = SiftMatcher().match(fa, fb)
    assert len(m) >= 200
    err = _match_errors(fa, fb, m)
    assert np.mean(err < CORRECT_PX) >= 0.95
    assert np.all((m.confidence >= 0) & (m.confidence <= 1))
    # one-to-one with the mutual check
    assert len(np.unique(m.idx_a)) == len(m) and len(np.unique(m.idx_b)) == len(m)
    # confidence ranks correct matches above wrong ones on average
    ok = err < CORRECT_PX
    if (~ok).sum() >= 2:
        assert m.confidence[ok].mean() > m.confidence[~ok].mean()


def test_ratio_and_mutual_checks_remove_wrong_matches(astronaut_features):
    fa, fb = astronaut_features
    plain = SiftMatcher(SiftSettings(ratio=1.0, mutual=False)).match(fa, fb)
    ratio_only = SiftMatcher(SiftSettings(ratio=0.8, mutual=False)).match(fa, fb)
    full = SiftMatcher(SiftSettings(ratio=0.8, mutual=True)).match(fa, fb)
    wrong = {name: int(np.sum(_match_errors(fa, fb, m) >= CORRECT_PX))
             for name, m in (("plain", plain), ("ratio", ratio_only), ("full", full))}
    assert len(plain) == len(fa)  # plain nearest neighbour keeps every keypoint of a
    # each check removes wrong matches; together they remove at least 90 % of them
    assert wrong["ratio"] < wrong["plain"] / 3
    assert wrong["full"] <= wrong["ratio"]
    assert wrong["full"] <= 0.1 * wrong["plain"]
    # ... while keeping most correct ones
    right_plain = len(plain) - wrong["plain"]
    right_full = len(full) - wrong["full"]
    assert right_full >= 0.8 * right_plain


def test_match_never_runs_the_detector(monkeypatch, astronaut_pair):
    calls = {"detect": 0}
    real_create = cv2.SIFT_create

    class Spy:
        def __init__(self, *args, **kwargs):
            self.inner = real_create(*args, **kwargs)

        def detectAndCompute(self, *args, **kwargs):
            calls["detect"] += 1
            return self.inner.detectAndCompute(*args, **kwargs)

        def detect(self, *args, **kwargs):
            calls["detect"] += 1
            return self.inner.detect(*args, **kwargs)

        def compute(self, *args, **kwargs):
            calls["detect"] += 1
            return self.inner.compute(*args, **kwargs)

    monkeypatch.setattr(cv2, "SIFT_create", Spy)
    m = SiftMatcher()
    fa = m.extract(astronaut_pair[0])
    fb = m.extract(astronaut_pair[1])
    assert calls["detect"] == 2
    for _ in range(3):
        assert len(m.match(fa, fb)) > 0
        assert len(m.match(fb, fa)) > 0
    assert calls["detect"] == 2


def test_nearest_two_matches_brute_force_for_any_block_size():
    rng = np.random.default_rng(3)
    a = normalize_descriptors(rng.random((41, 128)) * 255)
    b = normalize_descriptors(rng.random((29, 128)) * 255)
    D = np.linalg.norm(a[:, None].astype(np.float64) - b[None], axis=2)
    for block in (1, 2, 7, 41, 1000):
        nn_ab, d_ab, nn_ba, d_ba = nearest_two(a, b, block)
        np.testing.assert_array_equal(nn_ab, D.argmin(1))
        np.testing.assert_array_equal(nn_ba, D.argmin(0))
        np.testing.assert_allclose(d_ab, np.sort(D, 1)[:, :2], atol=1e-4)
        np.testing.assert_allclose(d_ba, np.sort(D, 0)[:2].T, atol=1e-4)


def test_ratio_match_on_constructed_descriptors():
    # b = a slightly perturbed and shuffled, plus one ambiguous pair of near-duplicates in b
    rng = np.random.default_rng(4)
    raw = rng.random((30, 128)) * 255
    a = normalize_descriptors(raw)
    perm = rng.permutation(30)
    b = normalize_descriptors(raw[perm] + rng.random((30, 128)) * 2)
    b = np.vstack([b, b[:1]])  # duplicate of b[0]: a[perm[0]] is ambiguous now
    m = ratio_match(a, b, ratio=0.8, mutual=True)
    expected = {perm[j]: j for j in range(1, 30)}
    assert len(m) == 29
    assert all(expected[i] == j for i, j in zip(m.idx_a.tolist(), m.idx_b.tolist()))
    assert perm[0] not in set(m.idx_a.tolist())


def test_edge_cases_give_empty_matches(astronaut_features):
    m = SiftMatcher()
    blank = m.extract(np.full((120, 160, 3), 128, np.uint8))
    assert len(blank) == 0 and blank.descriptors.shape == (0, 128) and blank.image_size == (160, 120)
    fa, _ = astronaut_features
    one = type(fa)(fa.keypoints[:1], fa.descriptors[:1], fa.scores[:1], fa.image_size)
    for x, y in ((blank, fa), (fa, blank), (blank, blank), (one, fa), (fa, one)):
        out = m.match(x, y)
        assert isinstance(out, Matches) and len(out) == 0


def test_bad_inputs_raise():
    m = SiftMatcher()
    with pytest.raises(ShapeError):
        m.extract(np.zeros((50, 50), np.uint8))
    with pytest.raises(ShapeError):
        m.extract(np.zeros((50, 50, 3), np.float32))
    with pytest.raises(SettingsError):
        SiftSettings(ratio=1.5)
    with pytest.raises(SettingsError):
        SiftSettings(max_features=0)


def test_registry_creates_sift():
    m = create_matcher("sift")
    assert isinstance(m, SiftMatcher) and m.name == "sift"
    assert isinstance(m, Matcher)
    assert create_matcher("sift", device="cpu").settings == SiftSettings()
    with pytest.raises(SettingsError, match="does not apply"):  # SIFT has no device to put on a GPU
        create_matcher("sift", device="cuda")


@pytest.mark.shared_data
def test_kitti_consecutive_frames():
    paths = [KITTI_DRIVE / "image_02" / "data" / f"{i:010d}.png" for i in (0, 1)]
    if not all(p.exists() for p in paths):
        pytest.skip("../shared/data/kitti_tiny is not available")
    images = [cv2.cvtColor(cv2.imread(str(p), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB) for p in paths]
    m = SiftMatcher()
    fa, fb = (m.extract(im) for im in images)
    matches = m.match(fa, fb)
    assert len(fa) > 1000 and len(fb) > 1000
    assert len(matches) >= 300
    # without poses: the matches must be consistent with one epipolar geometry
    pa = fa.keypoints[matches.idx_a].astype(np.float64)
    pb = fb.keypoints[matches.idx_b].astype(np.float64)
    _, inl = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.0, 0.999)
    assert inl is not None and inl.mean() >= 0.8
    assert _same_matches(fa.descriptors, fb.descriptors) == len(matches)  # 4000 x 4000 real descriptors


def _ratio_match_both_directions(a, b, ratio, mutual, block_rows):
    """The matcher before issue 11: both directions of nearest_two in full (the reference)."""
    nn_ab, d_ab, nn_ba, d_ba = nearest_two(a, b, block_rows)
    tiny = np.float32(1e-12)
    r = d_ab[:, 0] / np.maximum(d_ab[:, 1], tiny)
    keep = d_ab[:, 0] < ratio * d_ab[:, 1]
    if mutual:
        r_ba = (d_ba[:, 0] / np.maximum(d_ba[:, 1], tiny))[nn_ab]
        keep &= nn_ba[nn_ab] == np.arange(len(nn_ab))
        keep &= d_ba[nn_ab, 0] < ratio * d_ba[nn_ab, 1]
        r = np.maximum(r, r_ba)
    idx = np.flatnonzero(keep)
    return idx, nn_ab[idx], np.clip(1.0 - r[idx] / ratio, 0.0, 1.0).astype(np.float32)


def _same_matches(a, b, ratio=0.8, mutual=True, block_rows=2048):
    m = ratio_match(a, b, ratio, mutual, block_rows)
    idx_a, idx_b, conf = _ratio_match_both_directions(a, b, ratio, mutual, block_rows)
    np.testing.assert_array_equal(m.idx_a, idx_a)
    np.testing.assert_array_equal(m.idx_b, idx_b)
    assert m.confidence.dtype == np.float32 and m.confidence.tobytes() == conf.tobytes()  # bit for bit
    return len(m)


def test_reverse_direction_on_candidates_only_gives_the_full_matchers_matches(astronaut_pair):
    """ratio_match computes b -> a only for the b that can still match: the matches and their
    confidences equal those of both full directions, on real images and random descriptors."""
    m = SiftMatcher()
    fa, fb = m.extract(astronaut_pair[0]), m.extract(astronaut_pair[1])
    for block in (2048, 300, 7):
        assert _same_matches(fa.descriptors, fb.descriptors, block_rows=block) > 50
        assert _same_matches(fb.descriptors, fa.descriptors, block_rows=block) > 50
    assert _same_matches(fa.descriptors, fb.descriptors, ratio=1.0) > 50
    assert _same_matches(fa.descriptors, fb.descriptors, mutual=False) > 50
    rng = np.random.default_rng(7)
    for na, nb in ((2, 2), (5, 3000), (2500, 1700), (4000, 4000)):
        base = rng.random((max(na, nb), 128)) * 255
        a = normalize_descriptors(base[:na] + rng.random((na, 128)) * 40)
        b = normalize_descriptors(base[rng.permutation(len(base))[:nb]] + rng.random((nb, 128)) * 40)
        _same_matches(a, b)
        _same_matches(np.vstack([a, a[:3]]), np.vstack([b, b[:3]]))  # exact ties: duplicate descriptors


def test_extract_in_several_threads_at_once_gives_the_same_features(astronaut_pair):
    from concurrent.futures import ThreadPoolExecutor

    m = SiftMatcher()
    images = [astronaut_pair[k % 2][:, 16 * k:] for k in range(6)]
    alone = [m.extract(im) for im in images]
    with ThreadPoolExecutor(3) as pool:
        together = list(pool.map(m.extract, images))
    assert SiftMatcher.concurrent_extract
    for a, b in zip(alone, together):
        assert len(a) > 100
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.descriptors, b.descriptors)
