"""The evaluation's Markdown document, built only from the files of an evaluation folder.

:func:`write_document` reads ``results.csv``, ``frames.csv``, ``studies/*.csv`` and
``eval.json`` (and, for ``--compare-with``, the other folder's), writes the figures next
to the document (``<doc stem>/*.png``) and the Markdown (sections rendered by
:func:`vio_depth.report.to_markdown`, the run report's renderer). Every number in it comes
from those files.
"""

from __future__ import annotations

import json
from pathlib import Path

from vio_core.errors import InputError
from vio_core.limits import read_json_file

from ..io.depth_png import write_bytes_atomic
from ..report import Code, Image, Note, Section, Table, Text, to_markdown
from .figures import figure_study, figure_variants
from .results import compare_evaluations, read_csv
from .scores import FrameScore, common_frames, mean_on

_COLUMNS = (("delta1", "δ1", 4), ("abs_rel", "AbsRel", 4), ("rmse", "RMSE (m)", 3), ("r2", "R²", 4),
            ("coverage", "coverage", 3), ("points_per_frame", "points/frame", 0), ("point_error", "point error", 4),
            ("seconds_per_frame", "s/frame", 3))


def fmt(value, digits: int = 4) -> str:
    if value in (None, ""):
        return "–"
    v = float(value)
    return f"{v:.0f}" if digits == 0 else f"{v:.{digits}f}"


def _sequence_rows(meta: dict) -> list[list]:
    rows = []
    for s in meta["sequences"]:
        f = s["frames"]
        rows.append([s["label"], s["format"], f"{f['start']}-{f['stop'] - 1}", f["evaluated"],
                     s["disparity_kind"].upper() if s["disparity_kind"] == "simulated" else s["disparity_kind"],
                     s["mask"], s["pairing"], s["paper"]])
    return rows


def _results_section(rows: list[dict], labels: list[str]) -> Section:
    sec = Section("Results per sequence", "results", [Text(
        "One row per variant; every variant scores the same evaluated frames and averages its metrics "
        "over the frames it gave depth (coverage = those frames / evaluated frames).")])
    for label in labels:
        mine = [r for r in rows if r["sequence"] == label]
        if not mine:
            continue
        sec.blocks.append(Text(f"**{label}** ({mine[0]['mask']}, {mine[0]['evaluated_frames']} evaluated frames)"))
        sec.blocks.append(Table(["variant"] + [c[1] for c in _COLUMNS],
                                [[r["variant"]] + [fmt(r[k], d) for k, _, d in _COLUMNS] for r in mine]))
    return sec


def _same_frames_section(frames: list[dict], labels: list[str]) -> Section | None:
    by: dict[tuple, list[FrameScore]] = {}
    for r in frames:
        by.setdefault((r["sequence"], r["variant"]), []).append(FrameScore(
            frame=int(r["frame"]), status=r["status"], has_depth=r["has_depth"] == "true",
            delta1=float(r["delta1"]) if r["delta1"] else None, abs_rel=float(r["abs_rel"]) if r["abs_rel"] else None,
            rmse=float(r["rmse"]) if r["rmse"] else None))
    table = []
    for label in labels:
        wanted = [v for v in ("oracle", "sfm", "paper-reference") if (label, v) in by]
        if "sfm" not in wanted or "paper-reference" not in wanted:
            continue
        common = common_frames([by[(label, v)] for v in wanted])
        for v in wanted:
            m = mean_on(by[(label, v)], common)
            table.append([label, v, m["frames"], fmt(m["delta1"]), fmt(m["abs_rel"]), fmt(m["rmse"], 3)])
    if not table:
        return None
    return Section("Ours next to the paper-reference on the same frames", "same-frames", [
        Text("The frames where `oracle`, `sfm` and `paper-reference` all gave depth (the paper-reference drops "
             "frames without a qualifying pair), and each one's metrics averaged over exactly those frames."),
        Table(["sequence", "variant", "frames", "δ1", "AbsRel", "RMSE (m)"], table)])


def _study_section(folder: Path, fig_dir: Path, rel: str, names: list[str], n_frames: int) -> Section | None:
    sec = Section("Robustness studies", "studies", [Text(
        f"Each study sweeps one perturbation over a block of {n_frames} evaluated frames in the middle of each "
        "sequence (processed from 16 frames before the block), seeded per frame, the same draw at every "
        "value; cells are frame-averaged AbsRel, with the coverage in brackets when some frames got no depth. "
        "`ours` = our robust fit (MSAC + IRLS), `paper-reference` = scikit-learn "
        "RANSACRegressor at its defaults with the published depth formula, `least-squares` = plain least "
        "squares; all three on the same points.")])
    found = False
    for name in names:
        path = folder / "studies" / f"{name}.csv"
        if not path.is_file():
            continue
        rows = read_csv(path)
        if not rows:
            sec.blocks.append(Note(f"{name}: no sequence applies (see eval.json)"))
            continue
        found = True
        png = fig_dir / f"study_{name}.png"
        write_bytes_atomic(png, figure_study(name, rows[0]["parameter"], rows[0].get("unit", ""), rows))
        values = list(dict.fromkeys(r["value"] for r in rows))
        table = []
        for key in dict.fromkeys((r["sequence"], r["method"]) for r in rows):
            cells = {r["value"]: r for r in rows if (r["sequence"], r["method"]) == key}
            row = list(key)
            for v in values:
                c = cells.get(v)
                txt = "–" if c is None else fmt(c["abs_rel"])
                if c is not None and c["coverage"] not in ("", None) and float(c["coverage"]) < 1:
                    txt += f" ({float(c['coverage']):.2f})"
                row.append(txt)
            table.append(row)
        sec.blocks += [Text(f"**{name}** ({rows[0]['parameter']})"),
                       Image(f"{rel}/{png.name}", f"{name}: AbsRel and delta1 against {rows[0]['parameter']}"),
                       Table(["sequence", "method"] + [fmt(v, 3).rstrip("0").rstrip(".") for v in values], table)]
    return sec if found else None


def read_eval_meta(folder: Path) -> dict:
    """The ``eval.json`` of an evaluation folder (``--compare-with``), size and nesting checked
    and the fields the documents use validated.

    Raises:
        InputError: missing, unreadable, too large, or without those fields (names the file).
    """
    path = Path(folder) / "eval.json"
    try:
        meta = read_json_file(path, what="eval.json")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the evaluation's eval.json ({exc})") from None
    ok = (isinstance(meta, dict) and isinstance(meta.get("executor"), dict)
          and isinstance(meta["executor"].get("kind"), str)
          and all(isinstance(meta.get(k), (int, float)) and not isinstance(meta.get(k), bool)
                  for k in ("wall_seconds", "tasks", "tasks_cached")))
    if not ok:
        raise InputError(f"{path}: not the eval.json of a vio-depth evaluation (executor, wall_seconds, tasks, "
                         "tasks_cached expected)")
    return meta


def write_document(folder, doc_path, *, compare_with=None) -> Path:
    """Write the Markdown document of the evaluation in ``folder`` to ``doc_path`` (figures beside it).

    Args:
        folder: an evaluation folder (``vio-depth eval --out``).
        doc_path: the ``.md`` file; figures go to ``<doc_path without .md>/``.
        compare_with: another evaluation folder of the same command (e.g. on Ray): its wall
            time and whether every number agrees are stated.
    """
    folder, doc_path = Path(folder), Path(doc_path)
    meta = json.loads((folder / "eval.json").read_text())
    rows, frames = read_csv(folder / "results.csv"), read_csv(folder / "frames.csv")
    labels = [s["label"] for s in meta["sequences"]]
    fig_dir = doc_path.with_suffix("")
    fig_dir.mkdir(parents=True, exist_ok=True)
    rel = fig_dir.name
    simulated = [s["label"] for s in meta["sequences"] if s["disparity_kind"] == "simulated"]
    top = Section("Read this first", "first", [])
    if simulated:
        top.blocks.append(Note(f"The disparity of {', '.join(simulated)} is SIMULATED from the ground-truth depth "
                               "(random per-frame scale and shift, smooth distortion, noise), not a Depth Anything "
                               "prediction: these are figures on SIMULATED data. They compare rescaling methods on "
                               "equal inputs; they are not the paper's numbers."))
    run = Section("How these numbers were made", "how", [
        Text(f"vio-depth {meta['vio_depth_version']}, {meta['started']}, {meta['platform']}, {meta['cpu_count']} "
             f"CPU cores. Command (executor `{meta['executor']['kind']}`, {meta['executor']['workers']} workers):"),
        Code(" ".join(meta["command"]))])
    times = [["this run", meta["executor"]["kind"], meta["executor"]["workers"], f"{meta['wall_seconds']:.0f} s",
              meta["tasks"], meta["tasks_cached"]]]
    if compare_with is not None:
        other = read_eval_meta(Path(compare_with))
        cmp = compare_evaluations(folder, compare_with)
        times.append(["compared run", other["executor"]["kind"], other["executor"]["workers"],
                      f"{other['wall_seconds']:.0f} s", other["tasks"], other["tasks_cached"]])
        run.blocks += [Text("The same evaluation, run again with:"), Code(" ".join(other["command"])),
                       Text(f"**Identical numbers: {'yes' if cmp.identical else 'NO'}** -- {cmp.compared} cells of "
                            f"{', '.join(cmp.files)} compared (timings excepted)"
                            + ("" if cmp.identical else "; differences: " + "; ".join(cmp.differences[:10])))]
    run.blocks += [Table(["run", "executor", "workers", "wall time", "tasks", "of them from the cache"], times),
                   Note("Wall times were measured on a shared, loaded machine (other jobs ran at the same time): "
                        "they say how long this took here, not how fast the code is; so do the s/frame columns.")]
    protocol = Section("Protocol", "protocol", [
        Table(["sequence", "format", "frames processed", "evaluated", "disparity", "mask (caps, crop)", "pairing",
               "paper-reference preset"], _sequence_rows(meta)),
        Text("Masks: ground truth within the depth caps is scored (80 m outdoors, 10 m indoors); KITTI raw drives "
             "also use the Garg crop. Predictions are clamped to the caps; a pixel without a prediction counts at "
             "the far cap. Metrics per frame (δ1, AbsRel, RMSE) are averaged over the frames with depth; R² is the "
             "median over frames of the fit's coefficient of determination (1/z on d over its inliers); points/frame "
             "and point error are medians over frames of the number of points fed to the fit and of their median "
             "|z - z_gt| / z_gt (not for points taken from the ground truth); s/frame is each variant's own time "
             "per processed frame, disparity excluded."),
        Text("Variants: `oracle` = least squares on all ground-truth pixels of each frame (the best per-frame "
             "rescaling); `lidar:N` = our pipeline with N LiDAR beams sampled from the ground truth; `sfm` = our "
             "pipeline (SIFT, ground-truth poses, streaming rescaler, offline backfill, as `vio-depth run`); "
             "`sfm-no-ransac` = the same points with plain least squares per frame; `fixed` = one (alpha, beta) per "
             "sequence, least squares over every evaluated frame; `paper-reference` = the published code's choices "
             "(vio_depth/baselines/paper_reference.py). The SIMULATED disparity draws a new scale and shift for "
             "every frame (as Depth Anything normalises each image on its own), which is what `fixed` cannot "
             "follow.")])
    sections = [top, run, protocol, _results_section(rows, labels)]
    same = _same_frames_section(frames, labels)
    if same is not None:
        sections.append(same)
    png = fig_dir / "variants.png"
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    write_bytes_atomic(png, figure_variants(rows, labels, variants))
    sections.append(Section("AbsRel per variant", "figure", [Image(f"{rel}/{png.name}", "AbsRel per variant")]))
    studies = _study_section(folder, fig_dir, rel, meta.get("studies", []), meta.get("study_frames", 0))
    if studies is not None:
        sections.append(studies)
    text = to_markdown("Evaluation: the paper's protocol on the bundled and shared sequences", sections)
    write_bytes_atomic(doc_path, text.encode())
    return doc_path
