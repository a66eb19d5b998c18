"""SIMULATED disparity from sparse / holey ground truth: hull-limited densification, the
affine relation to the densified depth, determinism, the disparity-source contract, and
(when ../shared/data exists) one KITTI-tiny and one 7-Scenes frame."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError, ShapeError, UnknownNameError
from vio_depth.disparity import SimulatedDisparitySource
from vio_depth.disparity.densify import (
    FILL_METHODS,
    GtDisparitySettings,
    convex_hull_mask,
    densify_depth,
    simulate_gt_disparity,
)
from vio_depth.disparity.simulation import disparity_preset
from vio_depth.frame import Frame


def _gt_source(seed=0, settings=None):
    """The --disparity simulated source: densify the ground truth, then simulate."""
    return SimulatedDisparitySource(seed, densify=GtDisparitySettings() if settings is None else settings)

SHARED = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
H, W = 90, 120


def _plane_depth(h=H, w=W):
    """(h, w) metres, depth affine in the pixel coordinates: 4 m + 0.02 m/px * u + 0.05 m/px * v."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return 4.0 + 0.02 * u + 0.05 * v


def _lidar_like(depth, rng, rows=(30, None), fraction=0.08):
    """Sparse ground truth: a random ``fraction`` of the pixels of ``rows``, 0 elsewhere."""
    sparse = np.zeros_like(depth)
    r0, r1 = rows
    band = np.zeros(depth.shape, bool)
    band[r0:r1] = True
    keep = band & (rng.random(depth.shape) < fraction)
    sparse[keep] = depth[keep]
    return sparse


def _frame(gt, index=3):
    cam = Camera(gt.shape[1], gt.shape[0], 100.0, 100.0, gt.shape[1] / 2, gt.shape[0] / 2)
    return Frame(index=index, timestamp=0.1 * index, stem=f"{index:06d}", camera=cam, T_w_c=np.eye(4),
                 load_image=lambda: np.zeros((*gt.shape, 3), np.uint8),
                 load_gt_depth=lambda: gt.astype(np.float32))


def _inside_hull_bruteforce(valid, tol):
    """(H, W) bool: pixel centres inside the convex hull of the valid pixels, shrunk/grown by ``tol`` px."""
    rows, cols = np.nonzero(valid)
    hull = ConvexHull(np.stack([cols, rows], axis=1).astype(float))
    v, u = np.mgrid[0:valid.shape[0], 0:valid.shape[1]].astype(float)
    xy1 = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    # equations: a x + b y + c <= 0 inside, (a, b) unit normals
    return (np.max(xy1 @ hull.equations.T, axis=1) <= tol).reshape(valid.shape)


def test_linear_fill_reproduces_an_affine_depth_exactly_inside_the_hull_and_nan_outside():
    rng = np.random.default_rng(0)
    depth = _plane_depth()
    sparse = _lidar_like(depth, rng)
    dense = densify_depth(sparse, "linear")
    valid = sparse > 0
    assert np.array_equal(dense[valid], sparse[valid])  # ground truth kept as is
    # barycentric interpolation is exact for a depth affine in (u, v) inside the hull; the
    # rasterised hull's boundary pixels that stick out of it take the nearest value
    defined = np.isfinite(dense)
    in_hull = _inside_hull_bruteforce(valid, 1e-9)
    np.testing.assert_allclose(dense[in_hull], depth[in_hull], rtol=1e-9)
    # rows above the sampled band lie outside the hull: no depth there ("LiDAR FOV")
    first_row = np.nonzero(valid.any(axis=1))[0].min()
    assert not defined[:first_row].any()
    # every pixel inside the hull is filled, none more than a pixel outside it is
    assert defined[in_hull].all()
    assert not defined[~_inside_hull_bruteforce(valid, 1.0)].any()


def test_nearest_fill_takes_the_value_of_the_nearest_valid_pixel():
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.0, 50.0, (40, 50))
    sparse = np.where(rng.random(depth.shape) < 0.1, depth, 0.0)
    dense = densify_depth(sparse, "nearest")
    vr, vc = np.nonzero(sparse > 0)
    filled = np.isfinite(dense) & (sparse == 0)
    assert filled.sum() > 500
    fr, fc = np.nonzero(filled)
    d2 = (fr[:, None] - vr[None, :]) ** 2 + (fc[:, None] - vc[None, :]) ** 2
    nearest_d2 = d2.min(axis=1)
    # the value must be that of one of the (possibly tied) nearest valid pixels
    ties = d2 == nearest_d2[:, None]
    candidates = np.where(ties, sparse[vr, vc][None, :], np.nan)
    assert np.all(np.any(np.isclose(candidates, dense[fr, fc][:, None], rtol=0, atol=1e-12), axis=1))


def test_max_hole_px_leaves_far_hole_pixels_undefined():
    depth = _plane_depth()
    sparse = depth.copy()
    sparse[20:60, 30:90] = 0.0  # one 40 x 60 px hole, far inside the hull
    dense = densify_depth(sparse, "linear", max_hole_px=5.0)
    v, u = np.mgrid[0:H, 0:W]
    dist = np.minimum.reduce([v - 19, 60 - v, u - 29, 90 - u]).astype(float)  # to the nearest valid row/col
    in_hole = (sparse == 0)
    assert np.isfinite(dense[in_hole & (dist <= 5)]).all()
    assert np.isnan(dense[in_hole & (dist > 5)]).all()
    np.testing.assert_allclose(dense[np.isfinite(dense)], depth[np.isfinite(dense)], rtol=1e-9)


def test_hull_mask_matches_a_bruteforce_half_plane_test():
    rng = np.random.default_rng(2)
    valid = np.zeros((60, 80), bool)
    valid[rng.integers(10, 50, 25), rng.integers(5, 75, 25)] = True
    mask = convex_hull_mask(valid)
    assert mask[_inside_hull_bruteforce(valid, 0.0)].all()
    assert not mask[~_inside_hull_bruteforce(valid, 1.0)].any()
    assert not convex_hull_mask(np.zeros((5, 5), bool)).any()


@pytest.mark.parametrize("fill", FILL_METHODS)
def test_clean_model_is_exactly_affine_in_the_densified_disparity(fill):
    rng = np.random.default_rng(3)
    sparse = _lidar_like(_plane_depth(), rng)
    settings = GtDisparitySettings(fill=fill, model=disparity_preset("clean"))
    sim = simulate_gt_disparity(sparse, seed=5, frame_index=7, settings=settings)
    defined = np.isfinite(sim.dense_depth)
    assert np.array_equal(np.isfinite(sim.disparity), defined)  # NaN exactly where undefined
    metric = sim.alpha * sim.disparity[defined].astype(float) + sim.beta
    np.testing.assert_allclose(metric, 1.0 / sim.dense_depth[defined], rtol=1e-5)
    assert sim.disparity.dtype == np.float32


def test_default_model_stays_within_its_documented_distortion_and_noise():
    """Away from the hull boundary a smooth scene gets no edge blur; what remains is the
    <= 3 % multiplicative distortion and 0.2 %-of-peak noise."""
    rng = np.random.default_rng(4)
    sparse = _lidar_like(_plane_depth(), rng, rows=(0, None), fraction=0.2)
    sim = simulate_gt_disparity(sparse, seed=1, frame_index=0)
    inner = np.zeros((H, W), bool)
    inner[8:-8, 8:-8] = True
    rel = np.abs((sim.alpha * sim.disparity[inner] + sim.beta) * sim.dense_depth[inner] - 1.0)
    noise = 4 * 0.002 * 20.0 * sim.alpha * sim.dense_depth[inner]  # 4 sigma at the largest possible peak
    assert np.all(rel <= 0.03 + noise)


def test_source_contract_determinism_and_labels():
    rng = np.random.default_rng(5)
    gt = _lidar_like(_plane_depth(), rng)
    src = _gt_source(seed=11)
    assert src.kind == "simulated"
    a = src(_frame(gt, index=3))
    b = _gt_source(seed=11)(_frame(gt, index=3))
    c = src(_frame(gt, index=4))
    d = _gt_source(seed=12)(_frame(gt, index=3))
    assert a.shape == (H, W) and a.dtype == np.float32
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.allclose(a, c, equal_nan=True) and not np.allclose(a, d, equal_nan=True)
    finite = a[np.isfinite(a)]
    assert finite.size > 0 and np.all(finite >= 0)


def test_frames_without_ground_truth_give_none():
    gt = np.zeros((H, W))
    frame = _frame(gt)
    assert _gt_source()(frame) is None  # no valid pixel
    no_gt = Frame(0, 0.0, "x", frame.camera, np.eye(4), load_image=frame.load_image, load_gt_depth=None)
    assert _gt_source()(no_gt) is None


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(UnknownNameError, match="linear, nearest"):
        GtDisparitySettings(fill="cubic")
    with pytest.raises(UnknownNameError):
        densify_depth(np.ones((4, 4)), "bilinear")
    with pytest.raises(SettingsError):
        GtDisparitySettings(max_hole_px=0)
    with pytest.raises(InputError):
        _gt_source(seed=-1)
    with pytest.raises(ShapeError):
        densify_depth(np.ones((4, 4, 1)))
    wrong = _frame(np.ones((H, W)))
    wrong.load_gt_depth = lambda: np.ones((H + 1, W), np.float32)  # does not match the camera
    with pytest.raises(ShapeError):
        _gt_source()(wrong)


def _open_or_skip(name):
    from vio_depth.io import open_sequence

    path = SHARED / name
    if not path.is_dir():
        pytest.skip(f"{path} not available")
    return open_sequence(path)


@pytest.mark.shared_data
def test_kitti_tiny_frame_nan_above_the_lidar_and_affine_at_lidar_pixels():
    seq = _open_or_skip("kitti_tiny")
    frame = seq[2]
    gt = frame.gt_depth()
    src = _gt_source(seed=0)
    d = src(frame)
    sim = src.simulate(frame)
    assert d.shape == gt.shape
    lidar = gt > 0
    top = np.nonzero(lidar.any(axis=1))[0].min()
    assert top > 0 and np.isnan(d[:top]).all()  # above the LiDAR's vertical field of view
    assert np.isfinite(d[lidar]).all()
    # at the LiDAR pixels the true affine map gives back the LiDAR depth up to the model's
    # <= 3 % distortion (median; edges are blurred, far points carry the pixel noise)
    depth = 1.0 / (sim.alpha * d[lidar].astype(float) + sim.beta)
    assert np.median(np.abs(depth - gt[lidar]) / gt[lidar]) < 0.03


@pytest.mark.shared_data
def test_sevenscenes_frame_fills_kinect_holes_inside_the_hull():
    seq = _open_or_skip("7scenes_redkitchen")
    frame = seq[0]
    gt = frame.gt_depth()
    sim = _gt_source(seed=0).simulate(frame)
    valid = gt > 0
    hull = convex_hull_mask(valid)
    assert (hull & ~valid).sum() > 1000  # there are holes to fill
    assert np.isfinite(sim.disparity[hull]).all() and np.isnan(sim.disparity[~hull]).all()
    depth = 1.0 / (sim.alpha * sim.disparity[valid].astype(float) + sim.beta)
    assert np.median(np.abs(depth - gt[valid]) / gt[valid]) < 0.03
