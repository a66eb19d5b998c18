"""The sample fixtures (``mini_street``, ``digest``) live in ``tests/conftest.py``, shared with
``tests/robustness``."""

import numpy as np
import pytest


@pytest.fixture
def banded_gt():
    """(100, 50) float32 metres, valid on rows 10..89 only (like KITTI's projected LiDAR), with
    30 % holes (seed 0); rows 10 and 89 are valid in column 0, so the band is exactly 10..89."""
    rng = np.random.default_rng(0)
    gt = rng.uniform(1.0, 80.0, (100, 50)).astype(np.float32)
    gt[:10] = 0.0
    gt[90:] = 0.0
    gt[rng.random((100, 50)) < 0.3] = 0.0
    gt[10, 0] = gt[89, 0] = 5.0
    return gt

