"""SIMULATED affine-invariant disparity model: affine to 1/z away from edges, sky near 0, deterministic."""

import numpy as np
import pytest
from scipy import ndimage

from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_depth.disparity.simulation import DisparitySimulation, disparity_preset, disparity_presets, simulate_disparity

H, W = 120, 160


def _scene_depth():
    """Ground plane seen by a camera 1.5 m high (1/z affine in v), a fronto-parallel box
    at 4 m in front of it, and sky (0) in the upper part."""
    v = np.arange(H, dtype=float)[:, None] * np.ones((1, W))
    fy, cy = 150.0, 40.0
    with np.errstate(divide="ignore"):
        depth = np.where(v > cy + 1, fy * 1.5 / (v - cy), 0.0)
    depth[depth > 60] = 0.0  # far ground cut off: sky above
    box = np.zeros((H, W), bool)
    box[30:90, 60:110] = True
    depth[box] = np.minimum(np.where(depth[box] > 0, depth[box], np.inf), 4.0)
    return depth


def _masks(depth, model):
    valid = depth > 0
    edges = ndimage.binary_dilation(np.abs(np.diff(np.pad(depth, 1, mode="edge"), axis=0))[1:, 1:-1] +
                                    np.abs(np.diff(np.pad(depth, 1, mode="edge"), axis=1))[1:-1, 1:] > 0.2,
                                    iterations=int(np.ceil(4 * model.edge_sigma_px)) + 1)
    border = np.zeros_like(valid)
    m = int(np.ceil(4 * model.edge_sigma_px)) + 1
    border[m:-m, m:-m] = True
    return valid, edges, border


def test_affine_in_true_disparity_away_from_edges_within_documented_distortion():
    depth = _scene_depth()
    model = disparity_preset("default")
    sim = simulate_disparity(depth, seed=3, frame_index=7, model=model)
    d = sim.disparity.astype(np.float64)
    valid, edges, border = _masks(depth, model)
    keep = valid & ~edges & border
    assert keep.sum() > 3000
    q = 1.0 / depth[keep]
    clean = sim.scale * q + sim.shift
    resid = d[keep] - clean
    peak = d.max()
    bound = sim.scale * q * model.distortion + 5 * model.noise * peak
    assert np.all(np.abs(resid) <= bound)
    # the distortion is really there (not a trivially exact affine map)
    rel = np.abs(resid) / (sim.scale * q)
    assert np.percentile(rel, 90) > 0.2 * model.distortion
    # documented relation 1/depth = alpha d + beta
    np.testing.assert_allclose(sim.alpha * clean + sim.beta, q, rtol=1e-9)


def test_clean_preset_is_exactly_affine_and_sky_gets_the_shift():
    depth = _scene_depth()
    sim = simulate_disparity(depth, 1, 0, disparity_preset("clean"))
    valid = depth > 0
    np.testing.assert_allclose(sim.alpha * sim.disparity[valid] + sim.beta, 1.0 / depth[valid], rtol=2e-6)
    np.testing.assert_allclose(sim.disparity[~valid], sim.shift, rtol=1e-6)


def test_sky_is_small_positive_and_noisy():
    depth = _scene_depth()
    model = disparity_preset("default")
    sim = simulate_disparity(depth, 2, 5, model)
    valid, edges, border = _masks(depth, model)
    sky = sim.disparity[~valid & ~edges & border]
    assert len(sky) > 1000
    assert sky.min() >= 0.0
    assert sky.mean() < 0.04 * sim.disparity.max()  # near zero relative to the range
    assert sky.std() > 0  # noisy, not a constant
    assert np.mean(sky > 0) > 0.99


def test_depth_edges_are_softened():
    depth = _scene_depth()
    sim = simulate_disparity(depth, 2, 5, DisparitySimulation(edge_sigma_px=2.0, distortion=0.0, noise=0.0))
    row = sim.disparity[50]
    inside, outside = row[85], row[130]   # box (4 m) vs ground further away
    edge = row[108:112]                   # the box ends at column 110
    assert np.all((edge < inside - 1e-3) & (edge > outside + 1e-3))  # intermediate values: a ramp, not a step
    sharp = simulate_disparity(depth, 2, 5, disparity_preset("clean")).disparity[50]
    assert np.sum(np.abs(np.diff(sharp[100:120])) > 1e-3) == 1  # without softening: one jump


def test_deterministic_per_seed_and_frame_and_affine_varies_per_frame():
    depth = _scene_depth()
    a = simulate_disparity(depth, 11, 4)
    b = simulate_disparity(depth, 11, 4)
    assert np.array_equal(a.disparity, b.disparity) and a.scale == b.scale
    c = simulate_disparity(depth, 11, 5)
    e = simulate_disparity(depth, 12, 4)
    assert not np.array_equal(a.disparity, c.disparity) and not np.array_equal(a.disparity, e.disparity)
    alphas = {round(simulate_disparity(depth, 11, i).alpha, 9) for i in range(5)}
    assert len(alphas) == 5
    lo, hi = disparity_preset("default").peak_range
    assert all(lo * 0.95 <= simulate_disparity(depth, 11, i).disparity.max() <= hi * 1.05 for i in range(5))
    assert a.disparity.dtype == np.float32


def test_presets_and_json():
    assert disparity_presets() == ["clean", "default", "hard"]
    with pytest.raises(UnknownNameError, match="clean, default, hard"):
        disparity_preset("nope")
    m = disparity_preset("hard")
    assert DisparitySimulation.from_json(m.to_json()) == m
    with pytest.raises(SettingsError, match="blur"):
        DisparitySimulation.from_json({"blur": 2})
    with pytest.raises(SettingsError):
        DisparitySimulation(distortion=1.5)
    with pytest.raises(InputError):
        simulate_disparity(np.ones((4, 4)), -1, 0)
