"""Read a run's output folder: ``frames.jsonl``, ``metrics.json`` and which files it wrote.

Only the run's own files are read, so reports can be made for old output folders too.
Old runs have no run header; newer ones start ``frames.jsonl`` with a header record
``{"record": "run", "version": ..., "command_line": ..., "settings": {...}}`` and put the
same keys into ``metrics.json``. Unreadable lines are skipped with a note, never fatal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from vio_core.errors import InputError
from vio_core.limits import MAX_TEXT_BYTES, parse_json, read_json_file, read_limited, too_large

#: run-header keys and the names they may carry (the first one found wins)
HEADER_KEYS = {
    "version": ("version", "vio_depth_version"),
    "command_line": ("command_line", "command", "argv", "cmdline"),
    "settings": ("settings",),
}

#: folders of per-frame outputs a run may write, with the file pattern counted
OUTPUT_FOLDERS = (
    ("depth", "*.png", "16-bit depth PNGs (metres x 256, 0 = invalid)"),
    ("uncertainty", "*.png", "16-bit 1-sigma depth PNGs (metres x 256)"),
    ("depth_npy", "*.npy", "float32 depth, metres, NaN = invalid"),
    ("preview", "*.png", "colourised depth previews"),
    ("error", "*.png", "error maps against ground truth"),
    ("ply/sparse", "*.ply", "per-frame sparse points (PLY, world frame)"),
    ("ply/dense", "*.ply", "dense back-projected clouds (PLY, world frame)"),
    ("thumbs", "*", "thumbnails of the best, median and worst frames"),
)


@dataclass
class RunData:
    """What a run folder holds.

    Attributes:
        out_dir: the folder.
        frames: per-frame records of ``frames.jsonl`` in file order (header excluded).
        header: the run header record, or None for runs written without one.
        metrics: ``metrics.json``, or None (runs without ground truth have none).
        legend: ``thumbs/legend.json`` or ``preview/legend.json`` (colours of previews), or None.
        files: output folder -> (file count, description), only for folders present.
        notes: problems met while reading.
        name: the name the report shows for the folder ("" = the folder's own).
    """

    out_dir: Path
    frames: list = field(default_factory=list)
    header: dict | None = None
    metrics: dict | None = None
    legend: dict | None = None
    files: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    name: str = ""

    def info(self) -> dict:
        """``{"version", "command_line", "settings"}`` from the header (or from ``metrics.json``);
        values are None when not recorded."""
        out = {k: None for k in HEADER_KEYS}
        for source in (self.header, self.metrics):
            if not isinstance(source, dict):
                continue
            for key, names in HEADER_KEYS.items():
                if out[key] is None:
                    out[key] = next((source[n] for n in names if source.get(n) is not None), None)
        return out

    def series(self, key: str, sub: str | None = None) -> list[float]:
        """Per-frame numeric values of ``record[key]`` (or ``record[key][sub]``), NaN where missing."""
        out = []
        for r in self.frames:
            v = r.get(key)
            if sub is not None:
                v = v.get(sub) if isinstance(v, dict) else None
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            out.append(float(v) if ok else math.nan)
        return out

    def has(self, key: str, sub: str | None = None) -> bool:
        """Whether any frame carries a number under ``key`` (``[sub]``)."""
        return any(not math.isnan(v) for v in self.series(key, sub))


def _is_header(rec: dict) -> bool:
    return rec.get("record") == "run"


def load_run(out_dir) -> RunData:
    """Read the run folder ``out_dir``.

    Raises:
        InputError: the folder or its ``frames.jsonl`` is missing, or no line is a frame record.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: no such run folder")
    path = out_dir / "frames.jsonl"
    if not path.is_file():
        raise InputError(f"{path}: missing; is {out_dir} the --out folder of a finished vio-depth run?")
    run = RunData(out_dir=out_dir)
    try:
        data, size = read_limited(path, MAX_TEXT_BYTES)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if data is None:
        raise InputError(f"{path}: {too_large(size, MAX_TEXT_BYTES, 'a frames.jsonl')}")
    bad, wrong = [], []
    for n, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = parse_json(line)
        except ValueError:
            bad.append(n)
            continue
        if not isinstance(rec, dict):
            bad.append(n)
        elif _is_header(rec):
            if run.header is None:
                run.header = rec
        elif "frame" in rec:
            problem = record_problem(rec)
            if problem:
                wrong.append((n, problem))
            else:
                run.frames.append(rec)
        else:
            bad.append(n)
    if bad:
        run.notes.append(f"frames.jsonl: skipped {len(bad)} unreadable line(s) (first: line {bad[0]})")
    if wrong:
        run.notes.append(f"frames.jsonl: skipped {len(wrong)} frame record(s) with fields of the wrong type "
                         f"(first: line {wrong[0][0]}: {wrong[0][1]})")
    if not run.frames:
        why = f" (line {wrong[0][0]}: {wrong[0][1]})" if wrong else ""
        raise InputError(f"{path}: holds no usable frame records{why}")
    run.frames.sort(key=lambda r: r["frame"])
    run.metrics = _clean_metrics(_read_json(out_dir / "metrics.json", run.notes), run.notes)
    for name in ("thumbs/legend.json", "preview/legend.json"):
        run.legend = _clean_legend(_read_json(out_dir / name, run.notes), name, run.notes)
        if run.legend is not None:
            break
    for folder, pattern, words in OUTPUT_FOLDERS:
        d = out_dir / folder
        if d.is_dir():
            count = sum(1 for p in d.glob(pattern) if p.is_file() and not p.name.startswith("."))
            run.files[folder] = (count, words)
    if (out_dir / "ply" / "sparse_map.ply").is_file():
        run.files["ply/sparse_map.ply"] = (1, "merged sparse map (PLY, world frame)")
    return run


def _read_json(path: Path, notes: list) -> dict | None:
    if not path.is_file():
        return None
    try:
        value = read_json_file(path)
    except (ValueError, OSError):  # not JSON / UTF-8, too large, nested too deeply, unreadable
        notes.append(f"{path.name}: unreadable, ignored")
        return None
    return value if isinstance(value, dict) else None


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def record_problem(rec: dict) -> str:
    """Why a frame record cannot be reported ("" when it can): the fields the report uses
    must have their schema types (docs/frames_schema.md). A ``stem`` names files of the run
    folder, so it must be a plain file name (no folder, never ``..``)."""
    frame = rec.get("frame")
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        return f"'frame' must be a non-negative integer, got {frame!r:.40}"
    for key in ("status", "reason", "stem"):
        if key in rec and not isinstance(rec[key], str):
            return f"{key!r} must be a string, got {rec[key]!r:.40}"
    stem = rec.get("stem")
    if stem is not None and (stem in ("", ".", "..") or any(c in stem for c in "/\\\0")):
        return f"'stem' must be a file name, got {stem!r:.40}"
    if "backfilled" in rec and not isinstance(rec["backfilled"], bool):
        return f"'backfilled' must be true or false, got {rec['backfilled']!r:.40}"
    return ""


def _clean_metrics(metrics: dict | None, notes: list) -> dict | None:
    """``metrics.json`` with the parts the report reads checked: parts of the wrong type are
    dropped with a note (never a traceback on a damaged file)."""
    if metrics is None:
        return None
    dropped = []
    table = metrics.get("metrics")
    if table is not None and not (isinstance(table, dict) and all(isinstance(v, dict) for v in table.values())):
        dropped.append("metrics")
    pa = metrics.get("point_accuracy")
    if pa is not None and not (isinstance(pa, dict) and all(_number(pa.get(k)) for k in (
            "frames", "rel_err_median_of_frames", "rel_err_p90_median_of_frames", "points_per_frame_median"))):
        dropped.append("point_accuracy")
    n = metrics.get("frames_in_sequence")
    if n is not None and (isinstance(n, bool) or not isinstance(n, int)):
        dropped.append("frames_in_sequence")
    if not isinstance(metrics.get("disparity_kind", ""), str):
        dropped.append("disparity_kind")
    if dropped:
        notes.append(f"metrics.json: ignored {', '.join(dropped)} (wrong type)")
    return {k: v for k, v in metrics.items() if k not in dropped}


def _clean_legend(legend: dict | None, name: str, notes: list) -> dict | None:
    """A preview legend whose ``depth_range_m`` is two finite positive numbers (else None)."""
    if legend is None:
        return None
    r = legend.get("depth_range_m")
    if r is not None and not (isinstance(r, list) and len(r) == 2 and all(_number(v) and v > 0 for v in r)
                              and r[0] < r[1]):
        notes.append(f"{name}: ignored (depth_range_m is not two increasing positive numbers)")
        return None
    return legend
