"""Report plots: the data drawn are the records' values, PNGs have the stated size and content."""

import math

import cv2
import numpy as np
import pytest

pytest.importorskip("matplotlib")

from vio_depth.report import figure_dense_error, figure_point_accuracy, figure_points, figure_scale, figure_status
from vio_depth.report.load import RunData
from vio_depth.report.plots import DPI, STATUS_COLOURS, pixel_size, png_bytes, status_codes


def _run(n=20, gt=True, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        ok = i not in (0, 1, 9)
        rec = {"frame": i, "stem": f"{i:06d}", "status": "ok" if ok else ("no_pair" if i < 2 else "too_few_points"),
               "reason": "r", "matches": int(rng.integers(300, 600)), "triangulated_points": int(rng.integers(50, 200)),
               "inliers": int(rng.integers(20, 50))}
        if ok:
            a, b = 0.03 + 0.01 * math.sin(i / 3), 0.01 * math.cos(i / 4)
            rec.update(alpha=a, beta=b, sigma_alpha=0.001, sigma_beta=0.002,
                       fit_diagnostics={"alpha": a * 1.05, "beta": b, "sigma_alpha": 0.002, "sigma_beta": 0.003})
            if gt:
                rec.update(abs_rel=float(rng.uniform(0.01, 0.05)), oracle_abs_rel=0.01,
                           points_rel_err_median=float(rng.uniform(0.005, 0.02)), points_rel_err_p90=0.05)
        frames.append(rec)
    return RunData(out_dir=None, frames=frames)


def _decode(fig):
    return cv2.imdecode(np.frombuffer(png_bytes(fig), np.uint8), cv2.IMREAD_COLOR)[..., ::-1]


def _has_colour(img, hex_rgb, tol=40, min_pixels=30):
    rgb = np.array([int(hex_rgb[k:k + 2], 16) for k in (1, 3, 5)])
    return int((np.abs(img.astype(int) - rgb).sum(-1) < tol).sum()) >= min_pixels


def test_scale_plot_draws_alpha_beta_with_their_sigma_band():
    run = _run()
    fig = figure_scale(run)
    ax_a, ax_b = fig.axes
    alpha = np.array(run.series("alpha"))
    line = ax_a.lines[0]
    assert np.array_equal(line.get_xdata(), np.arange(20)) and np.array_equal(line.get_ydata(), alpha, equal_nan=True)
    # the band is +-1 sigma_alpha of the used value, and the own-fit dots are drawn (they differ here)
    band = ax_a.collections[0].get_paths()[0].vertices
    assert np.nanmax(band[:, 1]) == pytest.approx(np.nanmax(alpha) + 0.001)
    assert len(ax_a.lines) == 2 and np.allclose(ax_a.lines[1].get_ydata(), alpha * 1.05, equal_nan=True)
    lo, hi = ax_a.get_ylim()
    assert lo <= np.nanmin(alpha) and hi >= np.nanmax(alpha) and hi - lo < 3 * (np.nanmax(alpha) - np.nanmin(alpha))
    assert np.array_equal(ax_b.lines[0].get_ydata(), np.array(run.series("beta")), equal_nan=True)
    img = _decode(fig)
    assert img.shape == (*pixel_size(fig), 3) == (360, 750, 3)
    assert _has_colour(img, "#1f77b4")  # the alpha/beta line (matplotlib C0)
    assert img.min() < 60 and img.max() == 255  # text and white background


def test_scale_band_falls_back_to_the_own_fit_sigma_for_old_runs():
    run = _run()
    for r in run.frames:
        r.pop("sigma_alpha", None), r.pop("sigma_beta", None)
    band = figure_scale(run).axes[0].collections[0]
    assert "own fit" in band.get_label()
    assert np.nanmax(band.get_paths()[0].vertices[:, 1]) == pytest.approx(np.nanmax(run.series("alpha")) + 0.002)


def test_points_plot_and_status_timeline():
    run = _run()
    fig = figure_points(run)
    ys = {ln.get_label(): ln.get_ydata() for ln in fig.axes[0].lines}
    assert np.array_equal(ys["matches"], run.series("matches")) and np.array_equal(ys["inliers"], run.series("inliers"))
    names, codes = status_codes(run)
    assert names == ["ok", "no_pair", "too_few_points"] and codes.tolist()[:3] == [1, 1, 0] and codes[9] == 2
    fig = figure_status(run)
    img = _decode(fig)
    assert img.shape == (*pixel_size(fig), 3)
    for status in names:
        assert _has_colour(img, STATUS_COLOURS[status], tol=10)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["ok (17)", "no_pair (2)", "too_few_points (1)"]


def test_accuracy_plots_only_with_ground_truth():
    run = _run()
    fig = figure_dense_error(run)
    assert np.array_equal(fig.axes[0].lines[0].get_ydata(), run.series("abs_rel"), equal_nan=True)
    assert fig.axes[0].get_ylim()[0] == 0 and fig.axes[0].get_ylim()[1] >= np.nanmax(run.series("abs_rel"))
    assert figure_point_accuracy(run).axes[0].lines[1].get_label() == "90th percentile"
    no_gt = _run(gt=False)
    assert figure_dense_error(no_gt) is None and figure_point_accuracy(no_gt) is None
    none = RunData(out_dir=None, frames=[{"frame": 0, "stem": "0", "status": "no_pair"}])
    assert figure_scale(none) is None and figure_points(none) is None
    assert DPI == 100
