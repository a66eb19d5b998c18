"""The report's plots: matplotlib figures of a run's per-frame records (x axis: frame index).

Each ``figure_*`` function takes a :class:`~vio_depth.report.load.RunData` and returns a
``matplotlib.figure.Figure`` (object-oriented API with the Agg canvas: no pyplot, no global
backend change), or None when the run lacks the data. :func:`save_png` writes a figure at
a fixed pixel size (``FIGSIZE`` inches x ``DPI``). matplotlib is optional (the ``report``
extra) and imported only here, when a figure is made.
"""

from __future__ import annotations

import io

import numpy as np

from vio_core.errors import MissingDependencyError

from .load import RunData

DPI = 100
WIDTH_IN = 7.5

#: frame status -> colour of the status timeline (depth: greens/ambers; no depth: reds/greys)
STATUS_COLOURS = {
    "ok": "#2e9e44",
    "fallback_scale_only": "#f2b134",
    "fallback_previous_fit": "#e07b24",
    "no_pair": "#9e9e9e",
    "no_pose": "#6d6d6d",
    "too_few_matches": "#c2185b",
    "too_few_points": "#d32f2f",
    "ill_conditioned": "#7b1fa2",
    "no_consensus": "#5d4037",
    "uncertain_fit": "#ad1457",
    "pose_inconsistent": "#4a148c",
    "no_disparity": "#212121",
    "corrupt_image": "#b71c1c",
}
OTHER_STATUS_COLOUR = "#1565c0"


def _figure(height_in: float, rows: int = 1):
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingDependencyError("matplotlib", "report", "the run report (vio-depth report / --report)") from None
    fig = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, alpha=0.3, linewidth=0.6)
        ax.tick_params(labelsize=8)
    axes[-1].set_xlabel("frame", fontsize=8)
    return fig, axes


def _frames(run: RunData) -> np.ndarray:
    return np.array([r.get("frame", i) for i, r in enumerate(run.frames)], dtype=float)


def _finish(fig, title: str):
    fig.suptitle(title, fontsize=9)
    single = len(fig.axes) == 1
    fig.subplots_adjust(left=0.1, right=0.98, top=0.86 if single else 0.9, bottom=0.2 if single else 0.12, hspace=0.25)
    return fig


def figure_scale(run: RunData):
    """alpha and beta per frame with their 1-sigma band; None when no frame has a fit.

    The band is the sigma of the (alpha, beta) used (``sigma_alpha`` / ``sigma_beta`` of the
    record) or, for runs that did not record it, the sigma of the frame's own fit
    (``fit_diagnostics``). Own fits that differ from the value used (temporal filter,
    fallbacks) are drawn as dots.
    """
    if not run.has("alpha"):
        return None
    x = _frames(run)
    fig, (ax_a, ax_b) = _figure(3.6, rows=2)
    for ax, key in ((ax_a, "alpha"), (ax_b, "beta")):
        y = np.array(run.series(key))
        used_sigma = run.has(f"sigma_{key}")
        s = np.array(run.series(f"sigma_{key}") if used_sigma else run.series("fit_diagnostics", f"sigma_{key}"))
        band = "1σ" if used_sigma else "1σ of the frame's own fit"
        ax.fill_between(x, y - s, y + s, color="C0", alpha=0.25, linewidth=0, label=band)
        ax.plot(x, y, color="C0", linewidth=1.2, label=f"{key} used")
        own = np.array(run.series("fit_diagnostics", key))
        if np.any(np.isfinite(own) & (~np.isfinite(y) | (np.abs(own - np.nan_to_num(y)) > 1e-12))):
            ax.plot(x, own, linestyle="none", marker=".", markersize=3, color="C1", label=f"{key} of own fit")
        ax.set_ylabel("alpha (1/m)" if key == "alpha" else "beta (1/m)", fontsize=8)
        ax.legend(fontsize=7, loc="best", ncol=3, framealpha=0.7)
    return _finish(fig, "Scale alpha and shift beta of 1/depth = alpha·d + beta")


def figure_points(run: RunData):
    """Matches, triangulated points, points sampled in the disparity and fit inliers per frame."""
    keys = [(k, label) for k, label in (("matches", "matches"), ("triangulated_points", "triangulated"),
                                        ("points_sampled", "in disparity map"), ("inliers", "inliers"))
            if run.has(k)]
    if not keys:
        return None
    x = _frames(run)
    fig, (ax,) = _figure(2.6)
    styles = {"matches": dict(color="0.55", linewidth=1.0),
              "triangulated_points": dict(color="C0", linewidth=3.0, alpha=0.45),
              "points_sampled": dict(color="C2", linewidth=1.2, linestyle="--"),
              "inliers": dict(color="C3", linewidth=1.0, marker=".", markersize=3)}
    for key, label in keys:
        ax.plot(x, run.series(key), label=label, **styles[key])
    ax.set_ylim(bottom=0)
    ax.set_ylabel("count", fontsize=8)
    ax.legend(fontsize=7, loc="best", ncol=len(keys), framealpha=0.7)
    return _finish(fig, "Points and inliers per frame")


def status_codes(run: RunData) -> tuple[list[str], np.ndarray]:
    """Status names (in :data:`STATUS_COLOURS` order, then others) and the per-frame code (N,) int."""
    seen = [r.get("status", "unknown") for r in run.frames]
    names = [s for s in STATUS_COLOURS if s in seen] + sorted(set(seen) - set(STATUS_COLOURS))
    return names, np.array([names.index(s) for s in seen], dtype=int)


def figure_status(run: RunData):
    """One coloured cell per frame by status, with a legend of counts."""
    fig, (ax,) = _figure(2.2)
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    names, codes = status_codes(run)
    x = _frames(run)
    colours = [STATUS_COLOURS.get(n, OTHER_STATUS_COLOUR) for n in names]
    cmap = ListedColormap(colours)
    half = 0.5
    ax.imshow(codes[None, :], aspect="auto", cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5, interpolation="nearest",
              extent=(x.min() - half, x.max() + half, 0, 1))
    ax.set_yticks([])
    ax.grid(False)
    counts = [int((codes == k).sum()) for k in range(len(names))]
    ax.legend(handles=[Patch(color=c, label=f"{n} ({k})") for n, c, k in zip(names, colours, counts, strict=True)],
              fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.75), ncol=min(4, len(names)), frameon=False)
    fig.suptitle("Status per frame", fontsize=9)
    fig.subplots_adjust(left=0.04, right=0.98, top=0.86, bottom=0.52)
    return fig


def figure_dense_error(run: RunData):
    """AbsRel of the depth map per frame against ground truth, with the oracle fit; None without GT."""
    if not run.has("abs_rel"):
        return None
    x = _frames(run)
    fig, (ax,) = _figure(2.6)
    ax.plot(x, run.series("abs_rel"), color="C0", linewidth=1.2, marker=".", markersize=3, label="AbsRel (this run)")
    if run.has("oracle_abs_rel"):
        ax.plot(x, run.series("oracle_abs_rel"), color="0.45", linewidth=1.0, linestyle="--",
                label="oracle (best alpha, beta on all GT pixels)")
    ax.set_ylim(bottom=0)
    ax.set_ylabel("AbsRel", fontsize=8)
    ax.legend(fontsize=7, loc="best", framealpha=0.7)
    return _finish(fig, "Dense depth error against ground truth")


def figure_point_accuracy(run: RunData):
    """Median and p90 relative depth error of the triangulated points per frame; None without GT."""
    if not run.has("points_rel_err_median"):
        return None
    x = _frames(run)
    fig, (ax,) = _figure(2.6)
    ax.plot(x, run.series("points_rel_err_median"), color="C2", linewidth=1.2, marker=".", markersize=3,
            label="median |z - z_gt| / z_gt")
    if run.has("points_rel_err_p90"):
        ax.plot(x, run.series("points_rel_err_p90"), color="C3", linewidth=1.0, label="90th percentile")
    ax.set_ylim(bottom=0)
    ax.set_ylabel("relative error", fontsize=8)
    ax.legend(fontsize=7, loc="best", framealpha=0.7)
    return _finish(fig, "Triangulated points against ground truth")


def figure_trust(run: RunData):
    """Predicted error of each frame's fit (and the part its poses share) against the bound,
    the actual rescaling error where evaluated, and the pose-uncertainty inflation; None
    when no frame recorded a predicted error."""
    if not run.has("predicted_error"):
        return None
    x = _frames(run)
    inflation = run.has("pose_inflation")
    fig, axes = _figure(3.6 if inflation else 2.6, rows=2 if inflation else 1)
    ax = axes[0]
    ax.plot(x, run.series("predicted_error"), color="C0", linewidth=1.2, label="predicted error (fit used or refused)")
    if run.has("predicted_pose_error"):
        ax.plot(x, run.series("predicted_pose_error"), color="C4", linewidth=1.0, linestyle="--",
                label="of which the poses' (shared)")
    if run.has("rescale_abs_rel"):
        ax.plot(x, run.series("rescale_abs_rel"), linestyle="none", marker=".", markersize=4, color="C3",
                label="actual (against the oracle rescaling)")
    bound = (run.info().get("settings") or {}).get("rescaler", {}).get("max_fit_error")
    if isinstance(bound, (int, float)):
        ax.axhline(bound, color="0.3", linewidth=0.8, linestyle=":", label=f"max_fit_error {bound:g}")
    ax.set_ylim(bottom=0)
    ax.set_ylabel("relative depth error", fontsize=8)
    ax.legend(fontsize=7, loc="best", ncol=2, framealpha=0.7)
    if inflation:
        axes[1].plot(x, run.series("pose_inflation"), color="C5", linewidth=1.2, label="pose uncertainty inflation")
        axes[1].set_ylim(bottom=0.9)
        axes[1].set_ylabel("x stated sigma", fontsize=8)
        axes[1].legend(fontsize=7, loc="best", framealpha=0.7)
    return _finish(fig, "Predicted error of the rescaling, and how far the images say the poses are off")


def png_bytes(fig) -> bytes:
    """PNG bytes of ``fig`` at exactly ``figsize * DPI`` pixels, as a 256-colour palette PNG.

    Line plots hold a few hundred distinct colours (mostly anti-aliasing shades); median-cut
    quantisation without dithering keeps them visually identical at about 40 % of the size
    of matplotlib's RGBA PNG. Pillow comes with matplotlib.
    """
    from PIL import Image as PILImage

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white")
    rgb = PILImage.open(io.BytesIO(buf.getvalue())).convert("RGB")
    out = io.BytesIO()
    rgb.quantize(colors=256, method=PILImage.Quantize.MEDIANCUT, dither=PILImage.Dither.NONE).save(
        out, format="PNG", optimize=True)
    return out.getvalue()


def pixel_size(fig) -> tuple[int, int]:
    """(height, width) pixels of the PNG of ``fig``."""
    w, h = fig.get_size_inches()
    return int(round(h * DPI)), int(round(w * DPI))


#: name -> (figure function, alt text), in report order
FIGURES = {
    "scale": (figure_scale, "alpha and beta with 1-sigma bands per frame"),
    "points": (figure_points, "matches, triangulated points and inliers per frame"),
    "status": (figure_status, "status of every frame"),
    "dense_error": (figure_dense_error, "AbsRel per frame against ground truth"),
    "point_accuracy": (figure_point_accuracy, "relative error of the triangulated points per frame"),
    "trust": (figure_trust, "predicted and actual rescaling error per frame, and the pose uncertainty inflation"),
}
