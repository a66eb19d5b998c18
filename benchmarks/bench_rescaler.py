"""Benchmark: our rescaler fit (vio_depth.rescale.fit_affine) against the paper's
``sklearn.linear_model.RANSACRegressor(LinearRegression())`` at its defaults.

Both get identical synthetic inputs in the same process. Per cell (N points x outlier
ratio) we draw ``--datasets`` independent problems:

* affine-invariant disparity ``d ~ U(0.1, 1)`` at each point;
* true parameters ``alpha ~ U(0.05, 0.5)``, ``beta ~ U(0, 0.02)`` 1/m (depths ~2-200 m);
* each point has a metric-disparity uncertainty ``sigma_m_i = rel_i * (alpha d_i + beta)``
  with ``rel_i ~ U(0.01, 0.10)`` (1 % to 10 % of depth); inliers get Gaussian noise with that
  standard deviation, ``1/depth_i = alpha d_i + beta + sigma_m_i * e_i``, and report
  ``sigma_depth_i = sigma_m_i * depth_i**2`` (first-order depth uncertainty, as a
  triangulator computes it from geometry, independent of the noise draw);
* outliers: a fraction of the points gets a metric disparity uniform over
  ``[0.5 min(m), 1.5 max(m)]`` of the true metric disparities (uniformly spread).

scikit-learn gets the same target ``y = 1/depth`` and ``X = d[:, None]``; at its defaults the
inlier threshold is the median absolute deviation of ``y``, ``max_trials = 100`` with early
stopping at ``stop_probability = 0.99``, no weights, ``random_state = None`` (we seed numpy's
global generator before each call so that a run is reproducible; the error columns use the
first, untimed call). Ours runs with ``RansacSettings()`` defaults and the points'
``sigma_depth``.

Timing: median over all timed calls of a cell (``--datasets`` x ``--repeats`` per method;
per dataset each method is called once untimed, then ``--repeats`` times back to back).
Errors: mean over the datasets of ``|alpha_hat - alpha| / alpha`` and ``|beta_hat - beta|``
(1/m).

Exit status 1 when a done-when criterion fails: speed-up >= ``--min-speedup`` (20) in every
N = 1000 cell; our mean errors no larger than scikit-learn's in every cell; and at 50 %
outliers at most half of scikit-learn's.

Run: ``python benchmarks/bench_rescaler.py [--repeats 7] [--datasets 20]``.

Second mode, the temporal filter on a real or simulated sequence with ground-truth depth:
``python benchmarks/bench_rescaler.py --sequence DIR --points random:100 [--depth-noise 0.1]
[--outliers 0.2] [--max-depth 80]``. Per frame the reference points (``lidar:N`` or
``random:N`` from the ground truth, optionally with relative Gaussian depth noise and a
fraction of outliers log-uniform over the depth range) are rescaled by a ``per_frame``
Rescaler (no filter) and a ``streaming`` one (default Kalman filter, anchored on the
frame's disparity map); it prints frame-averaged AbsRel / delta1 against the ground truth
and the frame-to-frame jitter of the median rescaled depth (standard deviation of the
change of its logarithm). No pass/fail: this mode reports.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np

from vio_core.errors import MissingDependencyError
from vio_depth.rescale import RansacSettings, fit_affine

SIZES = (100, 1000, 10000)
OUTLIER_RATIOS = (0.0, 0.2, 0.5)


@dataclass(frozen=True)
class Problem:
    """One synthetic rescaling problem (arrays (N,); depth and sigma_depth in metres)."""

    d: np.ndarray
    depth: np.ndarray
    sigma_depth: np.ndarray
    alpha: float
    beta: float


def make_problem(n: int, outlier_ratio: float, rng: np.random.Generator) -> Problem:
    """Draw one problem with ``n`` points, a fraction ``outlier_ratio`` of them outliers."""
    alpha = rng.uniform(0.05, 0.5)
    beta = rng.uniform(0.0, 0.02)
    d = rng.uniform(0.1, 1.0, n)
    m_true = alpha * d + beta
    sigma_m = rng.uniform(0.01, 0.10, n) * m_true
    m = m_true + sigma_m * rng.standard_normal(n)
    n_out = int(round(outlier_ratio * n))
    out = rng.permutation(n)[:n_out]
    m[out] = rng.uniform(0.5 * m_true.min(), 1.5 * m_true.max(), n_out)
    depth = 1.0 / m
    return Problem(d, depth, sigma_m * depth**2, alpha, beta)


@dataclass
class Cell:
    n: int
    outlier_ratio: float
    ours_ms: float
    sklearn_ms: float
    ours_alpha_err: float
    sklearn_alpha_err: float
    ours_beta_err: float
    sklearn_beta_err: float
    ours_failed: int

    @property
    def speedup(self) -> float:
        return self.sklearn_ms / self.ours_ms


def run_cell(n: int, ratio: float, datasets: int, repeats: int, seed: int, use_sigma: bool) -> Cell:
    from sklearn.linear_model import LinearRegression, RANSACRegressor

    settings = RansacSettings()
    t_ours, t_sk = [], []
    ea_o, ea_s, eb_o, eb_s = [], [], [], []
    failed = 0
    for k in range(datasets):
        rng = np.random.default_rng([seed, n, int(ratio * 100), k])
        p = make_problem(n, ratio, rng)
        sigma = p.sigma_depth if use_sigma else None
        X = p.d[:, None]
        y = 1.0 / p.depth
        # timeit-style: each method's calls back to back (first call untimed), same process
        fit = fit_affine(p.d, p.depth, sigma, settings=settings)
        for _ in range(repeats):
            t0 = time.perf_counter()
            fit_affine(p.d, p.depth, sigma, settings=settings)
            t_ours.append(time.perf_counter() - t0)
        np.random.seed(k)
        sk = RANSACRegressor(LinearRegression()).fit(X, y)
        for r in range(repeats):
            np.random.seed(10_000 + k * repeats + r)
            t0 = time.perf_counter()
            RANSACRegressor(LinearRegression()).fit(X, y)
            t_sk.append(time.perf_counter() - t0)
        if not fit.ok:
            failed += 1
        ea_o.append(abs(fit.alpha - p.alpha) / p.alpha if fit.ok else np.inf)
        eb_o.append(abs(fit.beta - p.beta) if fit.ok else np.inf)
        ea_s.append(abs(float(sk.estimator_.coef_[0]) - p.alpha) / p.alpha)
        eb_s.append(abs(float(sk.estimator_.intercept_) - p.beta))
    return Cell(n, ratio, 1e3 * float(np.median(t_ours)), 1e3 * float(np.median(t_sk)),
                float(np.mean(ea_o)), float(np.mean(ea_s)), float(np.mean(eb_o)), float(np.mean(eb_s)), failed)


def format_table(cells: list[Cell]) -> str:
    head = ("| N | outliers | ours ms | sklearn ms | speed-up | ours abs(dalpha)/alpha | sklearn abs(dalpha)/alpha "
            "| ours abs(dbeta) 1/m | sklearn abs(dbeta) 1/m |")
    rows = [head, "|" + "---|" * 9]
    for c in cells:
        rows.append(f"| {c.n} | {c.outlier_ratio:.0%} | {c.ours_ms:.3f} | {c.sklearn_ms:.3f} | {c.speedup:.1f}x "
                    f"| {c.ours_alpha_err:.4f} | {c.sklearn_alpha_err:.4f} | {c.ours_beta_err:.5f} "
                    f"| {c.sklearn_beta_err:.5f} |")
    return "\n".join(rows)


def check(cells: list[Cell], min_speedup: float) -> list[str]:
    """Failed done-when criteria, in words (empty = all pass)."""
    failures = []
    for c in cells:
        tag = f"N={c.n}, outliers {c.outlier_ratio:.0%}"
        if c.n == 1000 and c.speedup < min_speedup:
            failures.append(f"{tag}: speed-up {c.speedup:.1f}x < {min_speedup:g}x")
        if c.ours_alpha_err > c.sklearn_alpha_err:
            failures.append(f"{tag}: alpha error {c.ours_alpha_err:.4g} > sklearn {c.sklearn_alpha_err:.4g}")
        if c.ours_beta_err > c.sklearn_beta_err:
            failures.append(f"{tag}: beta error {c.ours_beta_err:.4g} > sklearn {c.sklearn_beta_err:.4g}")
        if c.outlier_ratio >= 0.5 and (c.ours_alpha_err > 0.5 * c.sklearn_alpha_err
                                       or c.ours_beta_err > 0.5 * c.sklearn_beta_err):
            failures.append(f"{tag}: errors not clearly smaller (> half of sklearn's) at 50 % outliers")
        if c.ours_failed:
            failures.append(f"{tag}: our fit was not OK on {c.ours_failed} dataset(s)")
    return failures


def run_sequence(path: str, points: str, depth_noise: float, outliers: float, max_depth: float,
                 seed: int) -> None:
    """The temporal-filter report on one sequence (see the module docstring)."""
    from vio_depth.disparity import DisparitySettings, create_disparity_source
    from vio_depth.evaluation.metrics import average_metrics, compute_metrics
    from vio_depth.pipeline import parse_points_spec
    from vio_depth.io import open_sequence
    from vio_depth.rescale import Rescaler, RescalerSettings, sample_bilinear

    sequence = open_sequence(path)
    disparity_of = create_disparity_source(DisparitySettings(), sequence)
    spec = parse_points_spec(points, seed=seed)
    rng = np.random.default_rng(seed)
    rescalers = {"per_frame": Rescaler(RescalerSettings(temporal=None)), "streaming": Rescaler(RescalerSettings())}
    medians = {k: [] for k in rescalers}
    metrics = {k: [] for k in rescalers}
    gated = 0
    for frame in sequence:
        gt, disparity = frame.gt_depth(), disparity_of(frame)
        if gt is None or disparity is None:
            continue
        uv, depth = spec.sample(gt, frame.index)
        depth = depth * (1.0 + depth_noise * rng.standard_normal(len(depth)))
        n_out = int(round(outliers * len(depth)))
        out = rng.permutation(len(depth))[:n_out]
        depth[out] = np.exp(rng.uniform(np.log(depth.min()), np.log(depth.max()), n_out))
        d, inside = sample_bilinear(disparity, uv)
        for name, rescaler in rescalers.items():
            res = rescaler.update(d[inside], depth[inside], disparity_map=disparity)
            if res.filtered is not None and res.source.value == "frame" and not res.filtered.accepted:
                gated += 1
            pred = res.metric_depth(disparity)
            if pred is None:
                continue
            medians[name].append(float(np.nanmedian(pred)))
            metrics[name].append(compute_metrics(pred, gt, 1e-3, max_depth))
    print(f"# {path}: {len(sequence)} frames, points {spec}, depth noise {depth_noise:.0%}, "
          f"outliers {outliers:.0%}, max depth {max_depth:g} m, seed {seed}")
    print("| rescaler | frames with depth | AbsRel | delta1 | jitter of median depth |")
    print("|---|---|---|---|---|")
    for name in rescalers:
        m = average_metrics(metrics[name])
        jitter = float(np.std(np.diff(np.log(medians[name]))))
        print(f"| {name} | {m.n_frames} | {m.abs_rel:.4f} | {m.delta1:.4f} | {jitter:.4f} |")
    print(f"streaming: {gated} measurement(s) gated out")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per dataset and method (default 7)")
    parser.add_argument("--datasets", type=int, default=20, help="synthetic problems per cell (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic problems (default 0)")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="numbers of points")
    parser.add_argument("--min-speedup", type=float, default=20.0, help="required speed-up at N = 1000")
    parser.add_argument("--no-sigma", action="store_true", help="do not give sigma_depth to our fit")
    parser.add_argument("--sequence", help="temporal-filter report on this sequence folder instead")
    parser.add_argument("--points", default="random:100", help="reference points for --sequence (lidar:N, random:N)")
    parser.add_argument("--depth-noise", type=float, default=0.0, help="relative depth noise for --sequence")
    parser.add_argument("--outliers", type=float, default=0.0, help="outlier fraction for --sequence")
    parser.add_argument("--max-depth", type=float, default=80.0, help="evaluation depth cap for --sequence (m)")
    args = parser.parse_args(argv)
    if args.sequence:
        run_sequence(args.sequence, args.points, args.depth_noise, args.outliers, args.max_depth, args.seed)
        return 0
    try:
        import sklearn
    except ImportError as exc:
        raise MissingDependencyError("scikit-learn", "dev", "the rescaler benchmark") from exc

    print(f"# python {platform.python_version()}, numpy {np.__version__}, scikit-learn {sklearn.__version__}, "
          f"{platform.machine()}, {args.datasets} datasets x {args.repeats} repeats per cell"
          f"{', ours without sigma_depth' if args.no_sigma else ''}")
    cells = []
    for n in args.sizes:
        for ratio in OUTLIER_RATIOS:
            cells.append(run_cell(n, ratio, args.datasets, args.repeats, args.seed, not args.no_sigma))
            print(f"  done N={n} outliers={ratio:.0%}", file=sys.stderr)
    print(format_table(cells))
    failures = check(cells, args.min_speedup)
    for f in failures:
        print(f"FAIL {f}")
    print("all done-when criteria pass" if not failures else f"{len(failures)} criterion/criteria failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
