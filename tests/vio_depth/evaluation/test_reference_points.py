"""Tests of vio_depth/evaluation/reference_points.py: simulated LiDAR rows, random samples."""

from __future__ import annotations

import numpy as np
import pytest

from vio_core.errors import InputError
from vio_depth.evaluation.reference_points import beam_rows, lidar_beams, random_samples


def test_beam_rows_are_evenly_spaced_band_centres(banded_gt):
    gt = banded_gt  # band of 80 rows, 10..89
    assert beam_rows(gt, 1).tolist() == [50]  # 10 + floor(0.5 * 80)
    rows16 = beam_rows(gt, 16)
    assert rows16[0] == 12 and np.all(np.diff(rows16) == 5)  # 10 + floor((k + 0.5) * 5)
    rows32 = beam_rows(gt, 32)
    assert rows32[0] == 11 and rows32[-1] == 88 and len(set(rows32)) == 32
    full = beam_rows(gt, 4, over_valid_rows=False)  # whole height: 100 rows
    assert full.tolist() == [12, 37, 62, 87]
    assert len(beam_rows(gt, 80)) == 80
    with pytest.raises(InputError):
        beam_rows(gt, 81)
    with pytest.raises(InputError):
        beam_rows(np.zeros((5, 5)), 1)


def test_lidar_beams_take_every_valid_pixel_of_those_rows(banded_gt):
    gt = banded_gt
    uv, depth = lidar_beams(gt, 16)
    rows = beam_rows(gt, 16)
    assert set(uv[:, 1].astype(int)) <= set(rows.tolist())
    assert len(uv) == int((gt[rows] > 0).sum())
    np.testing.assert_array_equal(depth, gt[uv[:, 1].astype(int), uv[:, 0].astype(int)])
    assert np.all(depth > 0)


def test_random_samples(banded_gt):
    gt = banded_gt
    uv, depth = random_samples(gt, 500, seed=3)
    assert len(uv) == 500 and np.all(depth > 0)
    flat = uv[:, 1].astype(int) * gt.shape[1] + uv[:, 0].astype(int)
    assert len(np.unique(flat)) == 500  # distinct pixels
    np.testing.assert_array_equal(depth, gt.reshape(-1)[flat])
    uv2, _ = random_samples(gt, 500, seed=3)
    uv3, _ = random_samples(gt, 500, seed=4)
    assert np.array_equal(uv, uv2) and not np.array_equal(uv, uv3)
    small = np.zeros((4, 4))
    small[1, 2] = small[3, 0] = 2.0
    uv, depth = random_samples(small, 500)
    assert uv.tolist() == [[2.0, 1.0], [0.0, 3.0]] and depth.tolist() == [2.0, 2.0]
    with pytest.raises(InputError):
        random_samples(gt, 0)
