"""The evaluation's figures: AbsRel per variant and sequence, and one plot per robustness study.

matplotlib (the ``report`` extra) is imported only when a figure is made; PNGs are written
as 256-colour palette images by :func:`vio_depth.report.plots.png_bytes` (the run report's
writer), small enough for docs/ (a few tens of KB).
"""

from __future__ import annotations

import numpy as np

from vio_core.errors import MissingDependencyError

from ..report.plots import DPI, png_bytes

#: line styles of the study methods (same method = same style across sequences)
METHOD_STYLES = {"ours": "-", "ours (IMU poses)": "-", "paper-reference": "--", "least-squares": ":"}
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#7f7f7f",
           "#bcbd22")


def _figure(width_in: float, height_in: float, cols: int = 1):
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingDependencyError("matplotlib", "report", "the evaluation figures") from None
    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, cols, squeeze=False)[0]
    for ax in axes:
        ax.grid(True, alpha=0.3, linewidth=0.6)
        ax.tick_params(labelsize=7)
    return fig, axes


def figure_variants(rows: list[dict], sequences: list[str], variants: list[str]) -> bytes:
    """Grouped bars: frame-averaged AbsRel of each variant (bars) on each sequence (groups), log
    scale; the tables give each bar's coverage. ``rows``: ``results.csv`` rows (dicts)."""
    fig, (ax,) = _figure(7.5, 3.4)
    width = 0.8 / max(len(variants), 1)
    by = {(r["sequence"], r["variant"]): r for r in rows}
    for j, v in enumerate(variants):
        xs, ys, cov = [], [], []
        for i, s in enumerate(sequences):
            r = by.get((s, v))
            if r is None or r.get("abs_rel") in (None, ""):
                continue
            xs.append(i - 0.4 + width * (j + 0.5))
            ys.append(float(r["abs_rel"]))
            cov.append(float(r["coverage"]))
        ax.bar(xs, ys, width * 0.92, label=v, color=COLOURS[j % len(COLOURS)],
               hatch="//" if j >= len(COLOURS) else None)
    ax.set_xticks(range(len(sequences)))
    ax.set_xticklabels(sequences, fontsize=7)
    ax.set_ylabel("AbsRel (lower is better)", fontsize=8)
    ax.set_yscale("log")
    fig.legend(*ax.get_legend_handles_labels(), fontsize=6, ncol=min(len(variants), 5), loc="lower center",
               frameon=False)
    fig.suptitle("AbsRel per variant and sequence (frames with depth; see coverage in the tables)", fontsize=8)
    fig.subplots_adjust(left=0.08, right=0.99, top=0.91, bottom=0.1 + 0.045 * -(-len(variants) // 5))
    return png_bytes(fig)


def figure_study(name: str, parameter: str, unit: str, rows: list[dict]) -> bytes:
    """AbsRel and delta1 against the swept value; colour = sequence, line style = method.
    ``rows``: the study's CSV rows (dicts with sequence, method, value, abs_rel, delta1)."""
    fig, (ax_a, ax_d) = _figure(7.5, 3.6, cols=2)
    sequences = list(dict.fromkeys(r["sequence"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for i, s in enumerate(sequences):
        for m in methods:
            pts = [(float(r["value"]), r["abs_rel"], r["delta1"]) for r in rows
                   if r["sequence"] == s and r["method"] == m and r["abs_rel"] not in (None, "")]
            if not pts:
                continue
            x = np.array([p[0] for p in pts])
            style = dict(color=COLOURS[i % len(COLOURS)], linestyle=METHOD_STYLES.get(m, "-."), marker=".",
                         linewidth=1.1, markersize=4)
            ax_a.plot(x, [float(p[1]) for p in pts], label=f"{s}, {m}", **style)
            ax_d.plot(x, [float(p[2]) for p in pts], **style)
    for ax, label in ((ax_a, "AbsRel"), (ax_d, "delta1")):
        ax.set_xlabel(f"{parameter} ({unit})", fontsize=7)
        ax.set_ylabel(label, fontsize=8)
        values = sorted({float(r["value"]) for r in rows})
        if values and values[0] > 0 and values[-1] / values[0] >= 20:
            ax.set_xscale("log")
        elif len(values) > 2 and values[1] > 0 and values[-1] / values[1] >= 20:
            ax.set_xscale("symlog", linthresh=values[1])
    ax_a.set_yscale("log")
    handles, labels = ax_a.get_legend_handles_labels()
    ncol = 4
    fig.legend(handles, labels, fontsize=6, loc="lower center", ncol=ncol, frameon=False)
    fig.suptitle(f"Robustness: {name} (solid: ours, dashed: paper-reference, dotted: least squares)", fontsize=8)
    fig.subplots_adjust(left=0.08, right=0.99, top=0.9, bottom=0.14 + 0.04 * -(-len(labels) // ncol), wspace=0.25)
    return png_bytes(fig)
