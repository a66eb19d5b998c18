"""triangulation/batched.py: the batched helpers of the multi-view triangulation."""

import numpy as np

from triangulation.batched import sum_by


def test_sum_by_equals_one_bincount_per_component():
    """sum_by's single bincount over (group, component) bins sums each bin in row order,
    bit for bit as one bincount per component; float64 even when there is nothing to sum."""
    rng = np.random.default_rng(2)
    for m, n, shape in [(0, 0, (3, 3)), (0, 5, (3,)), (1000, 37, (3, 3)), (5000, 1200, (3,)), (7, 7, ())]:
        index = rng.integers(0, max(n, 1), m)
        values = rng.normal(size=(m, *shape)) * 10 ** rng.uniform(-10, 10, (m,) + (1,) * len(shape))
        flat = values.reshape(m, int(np.prod(shape, dtype=np.int64)))
        want = np.stack([np.bincount(index, weights=flat[:, k], minlength=n) for k in range(flat.shape[1])], 1)
        got = sum_by(index, values, n)
        assert got.dtype == np.float64 and got.shape == (n, *shape)
        assert np.array_equal(got.reshape(want.shape), want.astype(np.float64))
