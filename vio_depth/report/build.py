"""``vio-depth report OUT_DIR``: one HTML page and a Markdown twin about a finished run.

Reads only the run folder (:func:`~vio_depth.report.load.load_run`) and writes, into
``OUT_DIR/report/``::

    index.html          self-contained page (inline CSS, no scripts, no network)
    report.md           the same content as Markdown
    plots/*.png         small matplotlib plots (:mod:`.plots`) and colour legends
    thumbs/*            thumbnails of the best, median and worst frames

Every link is relative and points inside ``report/``, so the folder (or the whole run
folder) can be moved or copied elsewhere and still opens. Sections whose data the run
lacks (no ground truth, an old run without some fields, no previews) are left out with a
note saying why.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vio_core.errors import InputError, VioDepthError

from ..export.colormap import ERROR_LEVELS, colormap_lut
from ..export.exporter import resize_to_width
from ..export.preview import (
    ERROR_COLORMAP,
    PreviewSettings,
    depth_percentiles,
    depth_preview,
    read_png_rgb,
    run_depth_range,
    write_png_rgb,
)
from ..export.selection import has_depth, select_frames
from ..io.depth_png import read_depth_png, write_bytes_atomic
from ..io.marker import REPORT_MARKER, read_marker, write_marker
from .load import RunData, load_run
from .plots import FIGURES, png_bytes
from .render import Code, Image, Note, Section, Strip, Table, Text, to_html, to_markdown

THUMB_WIDTH = 300
MAX_STATUS_ROWS = 40


@dataclass
class ReportResult:
    """Where the report went and what it holds."""

    html: Path
    markdown: Path
    sections: list = field(default_factory=list)  # section titles, in order
    omitted: list = field(default_factory=list)  # notes on what could not be made
    images: list = field(default_factory=list)  # image paths relative to the report folder


def build_report(out_dir, report_dir=None, run_info: dict | None = None, name: str | None = None) -> ReportResult:
    """Write the report of the run in ``out_dir`` to ``report_dir`` (default ``out_dir/report``).

    Args:
        out_dir: a ``vio-depth run --out`` folder (needs ``frames.jsonl``).
        report_dir: where to write; created if missing. Its ``plots/`` and ``thumbs/`` are
            replaced.
        run_info: ``{"version", "command_line", "settings"}`` to show when the run's files do
            not record them (``vio-depth run --report`` passes its own).
        name: the run folder's name to show (default: ``out_dir``'s; a run builds its report
            in its staging folder and passes the name of ``--out``).

    Raises:
        InputError: no run folder / ``frames.jsonl``, or a ``report_dir`` that holds files
            vio-depth did not write (:func:`claim_report_dir`).
        MissingDependencyError: matplotlib is not installed (``pip install -e '.[report]'``).
    """
    run = load_run(out_dir)
    run.name = name or run.out_dir.resolve().name
    report_dir = Path(report_dir) if report_dir is not None else run.out_dir / "report"
    claim_report_dir(report_dir)
    for sub in ("plots", "thumbs"):
        if (report_dir / sub).is_dir():
            shutil.rmtree(report_dir / sub)
        (report_dir / sub).mkdir(parents=True, exist_ok=True)
    ctx = _Context(run, report_dir)
    plots = ctx.make_plots()

    sections = [
        _run_section(run, run_info),
        _summary_section(run),
        _plot_section("Scale over time", "scale", plots, ["scale"],
                      "The fit's alpha and beta per frame; the band is their 1-sigma uncertainty."),
        _plot_section("Points and inliers", "points", plots, ["points"], ""),
        _status_section(run, plots),
        _plot_section("Accuracy against ground truth", "accuracy", plots, ["dense_error", "point_accuracy"],
                      "Per-frame errors against the sequence's ground-truth depth."),
        _plot_section("Trust: predicted error and refusals", "trust", plots, ["trust"],
                      "A frame is written only while its predicted error is within max_fit_error; the poses' "
                      "uncertainty is inflated where the images show it too small (docs/error_model.md)."),
        _frames_section(ctx),
        _files_section(run),
    ]
    omitted = [b.text for s in sections for b in s.blocks if isinstance(b, Note) and b.text.startswith("Omitted")]
    if run.notes:
        sections.append(Section("Reading notes", "notes", [Text(n) for n in run.notes]))
    title = f"vio-depth run report: {run.name}"
    html_path, md_path = report_dir / "index.html", report_dir / "report.md"
    write_bytes_atomic(html_path, to_html(title, sections).encode("utf-8"))
    write_bytes_atomic(md_path, to_markdown(title, sections).encode("utf-8"))
    images = [b.src for s in sections for b in s.blocks if isinstance(b, Image)]
    images += [im.src for s in sections for b in s.blocks if isinstance(b, Strip)
               for _, _, ims in b.columns for im in ims if im is not None]
    return ReportResult(html_path, md_path, [s.title for s in sections], omitted, images)


def claim_report_dir(report_dir: Path) -> None:
    """Make ``report_dir`` a report folder: refuse one that holds anything without vio-depth's
    report marker (a report replaces its ``plots/`` and ``thumbs/`` and rewrites
    ``index.html`` and ``report.md``: ``--to ~/Documents`` would have deleted
    ``~/Documents/plots``), else create it and write the marker first (issue 23).

    Raises:
        InputError: a file, a link to nothing, or a non-empty folder without the marker.
    """
    if os.path.islink(report_dir) and not report_dir.exists():
        raise InputError(f"{report_dir}: is a symbolic link to nothing; not usable as a report folder")
    if report_dir.exists() and not report_dir.is_dir():
        raise InputError(f"{report_dir}: exists and is not a folder")
    try:
        entries = os.listdir(report_dir) if report_dir.is_dir() else []
        if entries and read_marker(report_dir, "report") is None:
            raise InputError(f"{report_dir}: not empty and holds no vio-depth report (no {REPORT_MARKER} marker); "
                             "vio-depth never replaces files it did not write (give another --to, or empty it)")
        report_dir.mkdir(parents=True, exist_ok=True)
        if read_marker(report_dir, "report") is None:
            write_marker(report_dir, "report")
    except OSError as exc:
        raise InputError(f"{report_dir}: cannot write the report ({exc.strerror or exc})") from None


class _Context:
    """The run and the report folder, with the helpers that write images into it."""

    def __init__(self, run: RunData, report_dir: Path):
        self.run = run
        self.dir = report_dir

    def make_plots(self) -> dict:
        """name -> Image for every figure the run's data allow (see :data:`FIGURES`)."""
        out = {}
        for name, (fn, alt) in FIGURES.items():
            fig = fn(self.run)
            if fig is None:
                continue
            write_bytes_atomic(self.dir / "plots" / f"{name}.png", png_bytes(fig))
            out[name] = Image(f"plots/{name}.png", alt)
        return out

    def write_rgb(self, rel: str, rgb) -> Image:
        write_png_rgb(self.dir / rel, rgb)
        return Image(rel, Path(rel).stem)


def _fmt(v, digits: int = 4) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _run_section(run: RunData, run_info: dict | None) -> Section:
    info = run.info()
    for k, v in (run_info or {}).items():
        if info.get(k) is None and v is not None:
            info[k] = v
    blocks = []
    cmd = info["command_line"]
    if isinstance(cmd, (list, tuple)):
        cmd = shlex.join(str(c) for c in cmd)
    blocks.append(Table(["", ""], [["folder", run.name],
                                   ["vio-depth version", _fmt(info["version"])],
                                   ["command line", _fmt(cmd)]]))
    if info["settings"] is not None:
        blocks.append(Code(json.dumps(info["settings"], indent=2, sort_keys=True, default=str), "settings"))
    missing = [k.replace("_", " ") for k in ("version", "command_line", "settings") if info[k] is None]
    if missing:
        blocks.append(Note(f"Not recorded by this run: {', '.join(missing)} (runs written before the run header "
                           "existed carry none)."))
    disp = (run.metrics or {}).get("disparity_kind") or (run.header or {}).get("disparity_kind")
    if disp == "simulated":
        blocks.append(Note("The disparity of this run is SIMULATED from ground-truth depth (not a Depth Anything "
                           "prediction): its figures say nothing about real predictions."))
    return Section("Run", "run", blocks)


def _summary_section(run: RunData) -> Section:
    frames = run.frames
    n_depth = sum(has_depth(r) for r in frames)
    counts: dict = {}
    for r in frames:
        counts[r.get("status", "unknown")] = counts.get(r.get("status", "unknown"), 0) + 1
    backfilled = sum(bool(r.get("backfilled")) for r in frames)
    text = f"{n_depth} of {len(frames)} processed frames got metric depth"
    if run.metrics and run.metrics.get("frames_in_sequence"):
        text += f" ({run.metrics['frames_in_sequence']} frames in the sequence)"
    text += "; statuses: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + "."
    if backfilled:
        text += f" {backfilled} frame(s) got depth in the offline backward pass."
    blocks = [Text(text)]
    m = (run.metrics or {}).get("metrics") or {}
    if m:
        rows = [[name, _fmt(v.get("delta1")), _fmt(v.get("abs_rel")), _fmt(v.get("rmse")), _fmt(v.get("n_frames"))]
                for name, v in m.items() if isinstance(v, dict)]
        blocks.append(Table(["points", "δ1", "AbsRel", "RMSE (m)", "frames evaluated"], rows))
        blocks.append(Text("oracle: (alpha, beta) fitted by least squares on all ground-truth pixels of each frame, "
                           "the best any rescaling of this disparity can do."))
    else:
        blocks.append(Note("Omitted: depth metrics (no metrics.json: the sequence has no ground-truth depth, "
                           "or the run did not finish)."))
    pa = (run.metrics or {}).get("point_accuracy")
    if isinstance(pa, dict) and pa.get("frames"):
        blocks.append(Text(f"Triangulated points against ground truth: median |z - z_gt| / z_gt "
                           f"{pa['rel_err_median_of_frames']:.3f}, p90 {pa['rel_err_p90_median_of_frames']:.3f} "
                           f"(medians over {pa['frames']} frames, {pa['points_per_frame_median']:.0f} points/frame)."))
    return Section("Summary", "summary", blocks)


def _plot_section(title: str, anchor: str, plots: dict, names: list, text: str) -> Section:
    blocks = [Text(text)] if text else []
    why = {
        "scale": "no frame has an (alpha, beta) fit",
        "points": "the records carry no point counts",
        "dense_error": "no per-frame AbsRel (the sequence has no ground-truth depth)",
        "point_accuracy": "no per-frame point errors (no ground-truth depth, or reference points instead of "
                          "triangulated ones)",
        "trust": "the records carry no predicted error (a run of an older version)",
    }
    for name in names:
        if name in plots:
            blocks.append(plots[name])
        else:
            blocks.append(Note(f"Omitted: plot of {FIGURES[name][1]} — {why.get(name, 'no data')}."))
    return Section(title, anchor, blocks)


def status_runs(frames) -> list[tuple[int, int, str, str]]:
    """Consecutive frames with the same status: ``[(first, last, status, first frame's reason)]``."""
    runs = []
    for r in frames:
        i, st = r.get("frame"), r.get("status", "unknown")
        if runs and runs[-1][2] == st and isinstance(i, int) and runs[-1][1] == i - 1:
            runs[-1][1] = i
        else:
            runs.append([i, i, st, str(r.get("reason", ""))])
    return [tuple(x) for x in runs]


def _status_section(run: RunData, plots: dict) -> Section:
    blocks = [plots["status"]] if "status" in plots else []
    bad = [r for r in status_runs(run.frames) if r[2] != "ok"]
    if not bad:
        blocks.append(Text("Every frame has status ok."))
        return Section("Status timeline", "status", blocks)
    rows = []
    for first, last, st, reason in bad[:MAX_STATUS_ROWS]:
        frames = f"{first}" if first == last else f"{first}–{last}"
        rows.append([frames, st, reason if len(reason) <= 200 else reason[:197] + "..."])
    blocks.append(Text("Frames whose status is not ok, with the reason of the first frame of each stretch:"))
    blocks.append(Table(["frames", "status", "reason"], rows))
    if len(bad) > MAX_STATUS_ROWS:
        blocks.append(Note(f"{len(bad) - MAX_STATUS_ROWS} more stretches not listed; see frames.jsonl."))
    return Section("Status timeline", "status", blocks)


def _legend_strip(lut: np.ndarray, reverse: bool) -> np.ndarray:
    """(14, 256, 3) uint8 colour bar of ``lut`` (reversed: index 255 on the left)."""
    strip = lut[::-1] if reverse else lut
    return np.ascontiguousarray(np.repeat(strip[None, :, :], 14, axis=0), dtype=np.uint8)


def _frames_section(ctx: _Context) -> Section:
    run = ctx.run
    selection = select_frames(run.frames)
    title, anchor = "Best, median and worst frames", "frames"
    if selection is None:
        return Section(title, anchor, [Note("Omitted: frame thumbnails — no frame has metric depth.")])
    legend = run.legend
    style = PreviewSettings()
    if legend:
        try:
            style = PreviewSettings(colormap=legend.get("colormap", "turbo"), scale=legend.get("scale", "log"),
                                    invalid_rgb=tuple(legend.get("invalid_rgb", (0, 0, 0))),
                                    error_range=float(legend.get("error_range", 0.2)))
        except (VioDepthError, TypeError, ValueError):  # an odd legend file: default colours, still a report
            legend = None
    depth_range = tuple(legend["depth_range_m"]) if legend and legend.get("depth_range_m") else None
    out, src = run.out_dir, ctx.dir
    columns, made_from_depth = [], False
    depth_cache = {}

    def depth_of(stem):
        if stem not in depth_cache:
            p = out / "depth" / f"{stem}.png"
            d = read_depth_png(p) if p.is_file() else None
            if d is not None:
                d[d <= 0] = np.nan
            depth_cache[stem] = d
        return depth_cache[stem]

    if depth_range is None:  # an old run without previews: one range over the frames shown
        depth_range = run_depth_range(depth_percentiles(d, style.percentiles)
                                      for d in (depth_of(s) for s in selection.stems) if d is not None)
    for label, rec in selection.frames.items():
        stem = rec["stem"]
        images = [None, None, None]
        thumbs = out / "thumbs"
        if (thumbs / f"{stem}_image.jpg").is_file():
            shutil.copyfile(thumbs / f"{stem}_image.jpg", src / "thumbs" / f"{stem}_image.jpg")
            images[0] = Image(f"thumbs/{stem}_image.jpg", f"image of frame {stem}")
        for k, kind, folder in ((1, "preview", "preview"), (2, "error", "error")):
            rel = f"thumbs/{stem}_{kind}.png"
            if (thumbs / f"{stem}_{kind}.png").is_file():
                shutil.copyfile(thumbs / f"{stem}_{kind}.png", src / rel)
            elif (out / folder / f"{stem}.png").is_file():
                write_png_rgb(src / rel, resize_to_width(read_png_rgb(out / folder / f"{stem}.png"), THUMB_WIDTH, True))
            elif kind == "preview" and depth_range is not None and depth_of(stem) is not None:
                write_png_rgb(src / rel, resize_to_width(depth_preview(depth_of(stem), depth_range, style),
                                                         THUMB_WIDTH, True))
                made_from_depth = True
            else:
                continue
            images[k] = Image(rel, f"{kind} of frame {stem}")
        value = rec.get(selection.criterion)
        columns.append((f"{label}: frame {rec.get('frame')}", f"{selection.criterion} {_fmt(value)}", images))
    blocks = [Text(f"Frames with depth ranked by {selection.description} ({selection.criterion}).")]
    rows = ["image", "depth", "error vs GT"]
    keep = [k for k in range(3) if any(c[2][k] is not None for c in columns)]
    blocks.append(Strip([rows[k] for k in keep], [(t, c, [ims[k] for k in keep]) for t, c, ims in columns]))
    if 0 not in keep:
        blocks.append(Note("Omitted: image thumbnails — written only by `vio-depth run --report`."))
    if depth_range is not None and 1 in keep:
        ctx.write_rgb("plots/depth_legend.png", _legend_strip(colormap_lut(style.colormap), reverse=True))
        blocks.append(Image("plots/depth_legend.png", "depth colour scale",
                            f"depth colours: near {depth_range[0]:.3g} m (left) to far {depth_range[1]:.3g} m (right), "
                            f"{style.scale} scale, {style.colormap}; invalid pixels "
                            f"rgb{tuple(int(c) for c in style.invalid_rgb)}"
                            + ("; drawn from the 16-bit depth PNGs" if made_from_depth else "")))
    if 2 in keep:
        ctx.write_rgb("plots/error_legend.png", _legend_strip(colormap_lut(ERROR_COLORMAP)[:ERROR_LEVELS], reverse=False))
        r = style.error_range
        blocks.append(Image("plots/error_legend.png", "error colour scale",
                            f"error (depth - gt) / gt: {-r:+.0%} (left, blue: too near) to {r:+.0%} "
                            f"(right, red: too far); pixels without ground truth black"))
    else:
        blocks.append(Note("Omitted: error-map thumbnails — need ground-truth depth and a run with --report or "
                           "--save-preview."))
    return Section(title, anchor, blocks)


def _files_section(run: RunData) -> Section:
    rows = [["frames.jsonl", len(run.frames), "one JSON record per processed frame"]]
    if run.metrics is not None:
        rows.append(["metrics.json", 1, "averaged metrics against ground truth"])
    rows += [[f"{folder}/" if not folder.endswith(".ply") else folder, n, words]
             for folder, (n, words) in run.files.items()]
    return Section("Files of this run", "files", [
        Text("Paths relative to the run folder (the report links only to its own copies)."),
        Table(["path", "files", "what"], rows)])
