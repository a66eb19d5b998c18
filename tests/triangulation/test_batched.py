"""triangulation/batched.py: the batched helpers of the multi-view triangulation."""

import numpy as np

from triangulation.batched import inv2, inv3, quad2, solve3, sum_by


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


def test_closed_form_2x2_inverse_and_quadratic_form():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(50, 2, 2))
    S = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(2)
    np.testing.assert_allclose(inv2(S), np.linalg.inv(S), rtol=1e-10)
    r = rng.normal(size=(50, 2))
    np.testing.assert_allclose(quad2(r, S), np.einsum("ni,nij,nj->n", r, S, r), rtol=1e-12)


def test_closed_form_3x3_inverse_and_solve_match_lapack_and_flag_singular_rows():
    """inv3/solve3 (adjugate) agree with numpy's LU on well-conditioned normal matrices, flag
    singular, ill-conditioned and non-finite rows with NaN and False, and compute each row on
    its own (the same result whatever rows come along)."""
    rng = np.random.default_rng(3)
    J = rng.normal(size=(200, 6, 3))
    A = np.transpose(J, (0, 2, 1)) @ J * 10 ** rng.uniform(-6, 6, (200, 1, 1))  # SPD, scaled
    b = rng.normal(size=(200, 3))
    inv, ok = inv3(A)
    assert ok.all()
    np.testing.assert_allclose(inv, np.linalg.inv(A), rtol=1e-9, atol=0)
    x, ok = solve3(A, b)
    np.testing.assert_allclose(x, np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-9, atol=0)
    bad = A.copy()
    bad[0] = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])  # rank 1
    bad[1] = np.diag([1.0, 1.0, 1e-15])  # |det| 1e-15 <= 1e-12 trace^3
    bad[2, 0, 0] = np.nan
    x, ok = solve3(bad, b)
    assert not ok[:3].any() and ok[3:].all()
    assert np.isnan(x[:3]).all() and np.isfinite(x[3:]).all()
    np.testing.assert_array_equal(x[3:], solve3(A[3:], b[3:])[0])  # row-wise: bit for bit
