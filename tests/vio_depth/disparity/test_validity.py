"""Issue 12, case 6/7 (disparity): unusable maps are a per-frame status, never a silently wrong map.

Unit checks of :mod:`vio_depth.disparity.validity`, then the pipeline on the street sample
(SIMULATED disparity): after good frames, an all-zero, all-NaN or inverted map gets status
``invalid_disparity`` and no depth (before: the previous fit was applied to it, giving a
constant or inverted depth map marked ``fallback_previous_fit``); a map with NaN pixels is
masked there.
"""

from pathlib import Path

import numpy as np
import pytest

from vio_depth import FrameStream, PipelineSettings, open_sequence
from vio_depth.disparity import (
    DisparitySettings,
    check_inversion,
    check_map_content,
    create_disparity_source,
    rank_correlation,
)
from vio_depth.pipeline import FrameStatus
from vio_depth.rescale import FitSource

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"


def test_map_content_checks():
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 1, (20, 30)).astype(np.float32)
    assert check_map_content(d).ok
    d_neg = d - 5.0  # negative after a shift: still valid
    assert check_map_content(d_neg).ok
    assert not check_map_content(np.zeros((20, 30), np.float32)).ok
    res = check_map_content(np.full((20, 30), np.nan, np.float32))
    assert not res.ok and res.valid_fraction == 0.0 and "no valid" in res.reason
    sparse = np.full((20, 30), np.nan, np.float32)
    sparse[:1, :30] = d[:1]  # 5 % valid
    res = check_map_content(sparse)
    assert not res.ok and "min_valid_fraction" in res.reason
    holes = d.copy()
    holes[:, :10] = np.nan
    res = check_map_content(holes)
    assert res.ok and res.valid_fraction == pytest.approx(2 / 3)


def test_rank_correlation_and_inversion():
    rng = np.random.default_rng(1)
    z = rng.uniform(2, 50, 200)
    d = 3.0 / z + 0.1
    assert rank_correlation(d, 1 / z) == pytest.approx(1.0)
    assert rank_correlation(-d, 1 / z) == pytest.approx(-1.0)
    assert rank_correlation(np.ones(5), np.arange(5.0)) != rank_correlation(np.ones(5), np.arange(5.0))  # NaN
    assert check_inversion(d, z).ok
    bad = check_inversion(-d, z)
    assert not bad.ok and "inverted" in bad.reason
    assert not check_inversion(z, z).ok  # a depth map instead of a disparity
    assert check_inversion(-d[:5], z[:5]).ok  # too few points to tell
    noisy = d + rng.normal(0, 0.05, len(d))
    assert check_inversion(noisy, z).ok


def test_min_valid_fraction_is_a_validated_setting():
    from vio_core.errors import SettingsError

    with pytest.raises(SettingsError, match="min_valid_fraction"):
        DisparitySettings(min_valid_fraction=1.5)
    assert DisparitySettings().min_valid_fraction == 0.10


@pytest.fixture(scope="module")
def street():
    if not (STREET / "sequence.json").exists():
        pytest.skip("bundled street sample missing")
    seq = open_sequence(STREET)
    return seq, create_disparity_source(DisparitySettings(), seq)


def _stream_until(seq, disparity, n_good, bad):
    stream = FrameStream(seq.camera, PipelineSettings())
    for i in range(n_good):
        f = seq[i]
        last = stream.push(f.image(), disparity(f), timestamp=f.timestamp, T_w_c=f.T_w_c)
    assert last.status == FrameStatus.OK
    f = seq[n_good]
    return stream.push(f.image(), bad(disparity(f)), timestamp=f.timestamp, T_w_c=f.T_w_c)


@pytest.mark.parametrize("kind", ["zero", "nan", "negated", "depth"])
def test_an_unusable_map_after_good_frames_gets_no_depth(street, kind):
    seq, disparity = street
    bad = {"zero": lambda d: np.zeros_like(d), "nan": lambda d: np.full_like(d, np.nan),
           "negated": lambda d: -d, "depth": lambda d: (1.0 / np.maximum(d, 0.05)).astype(np.float32)}[kind]
    res = _stream_until(seq, disparity, 6, bad)
    assert res.status == FrameStatus.INVALID_DISPARITY, (res.status, res.reason)
    assert res.depth is None and res.rescale.source == FitSource.NONE
    assert res.reason


def test_nan_pixels_are_masked_not_fitted_through(street):
    seq, disparity = street
    f = seq[6]
    clean = _stream_until(seq, disparity, 6, lambda d: d)
    holes = _stream_until(seq, disparity, 6, lambda d: np.where(np.arange(d.shape[1]) < 200, np.nan, d)
                          .astype(np.float32))
    assert holes.status == FrameStatus.OK and holes.disparity_valid_fraction == pytest.approx(1 - 200 / 640)
    assert np.isnan(holes.depth[:, :200]).all()  # no depth where the disparity is invalid
    assert (holes.points_uv[:, 0] >= 199).all()  # no point on the masked pixels was fitted
    gt = f.gt_depth()
    ok = np.isfinite(holes.depth) & (gt > 0)
    assert np.median(np.abs(holes.depth[ok] - gt[ok]) / gt[ok]) < 0.05
    assert abs(holes.fit.alpha / clean.fit.alpha - 1) < 0.1
