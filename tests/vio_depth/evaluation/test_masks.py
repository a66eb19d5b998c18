"""EvalMask: the caps are checked, the Garg / Eigen crops keep exactly the published integer bounds."""

import numpy as np
import pytest

from vio_core.errors import SettingsError, UnknownNameError
from vio_depth.evaluation import EvalMask, compute_metrics, crop_bounds


def test_garg_crop_of_a_kitti_image_has_the_published_bounds():
    # int(0.40810811 * 375) = 153, int(0.99189189 * 375) = 371, int(0.03594771 * 1242) = 44, ... = 1197
    assert crop_bounds("garg", 375, 1242) == (153, 371, 44, 1197)
    assert crop_bounds("eigen", 375, 1242) == (124, 342, 44, 1197)
    assert crop_bounds("none", 375, 1242) is None


def test_apply_zeroes_ground_truth_outside_the_crop_only():
    gt = np.full((100, 200), 5.0, np.float32)
    out = EvalMask(crop="garg").apply(gt)
    r0, r1, c0, c1 = crop_bounds("garg", 100, 200)
    assert np.all(out[r0:r1, c0:c1] == 5.0)
    assert np.count_nonzero(out) == (r1 - r0) * (c1 - c0)
    assert np.all(gt == 5.0)  # the input is not modified
    assert EvalMask().apply(gt) is gt or np.array_equal(EvalMask().apply(gt), gt)


def test_cropped_metrics_ignore_errors_outside_the_crop():
    gt = np.full((100, 200), 10.0, np.float32)
    pred = gt.copy()
    pred[:20] = 30.0  # wrong only in the sky rows, which the Garg crop removes
    mask = EvalMask(crop="garg")
    assert compute_metrics(pred, mask.apply(gt)).abs_rel == 0.0
    assert compute_metrics(pred, gt).abs_rel == pytest.approx(0.4)


def test_invalid_caps_and_unknown_crops_are_refused():
    with pytest.raises(SettingsError, match="min_depth < max_depth"):
        EvalMask(min_depth=10.0, max_depth=10.0)
    with pytest.raises(UnknownNameError, match="garg"):
        EvalMask(crop="kb")
    assert EvalMask(max_depth=10.0).describe() == "depth 0.001-10 m, no crop"
