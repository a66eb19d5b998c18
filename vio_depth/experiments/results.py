"""The files of an evaluation folder, and the comparison of two evaluations number by number.

=========================  =====================================================================
file                       content
=========================  =====================================================================
``results.csv``            one row per sequence x variant (:data:`RESULT_COLUMNS`)
``frames.csv``             one row per sequence x variant x evaluated frame
``studies/<study>.csv``    one row per sequence x method x swept value
``eval.json``              the command, version, executor, wall time, sequences and settings
``cache/``                 task results (``tasks/``) and disparity maps (``disparity/``): resume
=========================  =====================================================================

Floats are written with Python's shortest round-trip form (``repr``), so a file read back
gives the numbers computed, and two runs with identical results write identical cells.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..io.depth_png import write_bytes_atomic
from .scores import ROW_COLUMNS, TIMING_COLUMNS

RESULT_COLUMNS = ("sequence", "variant", "disparity", "mask", "evaluated_frames") + ROW_COLUMNS + ("statuses",)
FRAME_COLUMNS = ("sequence", "variant", "frame", "status", "has_depth", "delta1", "abs_rel", "rmse",
                 "pixel_coverage", "r2", "points", "point_error")
STUDY_COLUMNS = ("sequence", "study", "method", "parameter", "value", "frames", "frames_with_depth", "coverage",
                 "delta1", "abs_rel", "rmse")


def cell(value) -> str:
    """CSV text of a value: '' for None / NaN, ``repr`` for floats, JSON for dicts."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    return str(value)


def csv_text(columns, rows) -> str:
    """CSV of ``rows`` (dicts) with ``columns`` in order, ``\\n`` line ends."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([cell(r.get(c)) for c in columns])
    return buf.getvalue()


def write_csv(path, columns, rows) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, csv_text(columns, rows).encode())
    return path


def read_csv(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def write_json(path, data) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())
    return path


@dataclass
class Comparison:
    """Result of :func:`compare_evaluations`: ``compared`` cells, the ``differences`` (file: row, column)."""

    compared: int = 0
    files: list[str] = field(default_factory=list)
    differences: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return not self.differences and self.compared > 0


def _csv_files(folder: Path) -> list[str]:
    names = [n for n in ("results.csv", "frames.csv") if (folder / n).is_file()]
    if (folder / "studies").is_dir():
        names += sorted(f"studies/{p.name}" for p in (folder / "studies").glob("*.csv"))
    return names


def compare_evaluations(a, b) -> Comparison:
    """Compare every CSV cell of two evaluation folders except timings (:data:`TIMING_COLUMNS`).

    Files present in only one folder, and rows or columns that differ in number, are
    differences too.
    """
    a, b = Path(a), Path(b)
    out = Comparison()
    names_a, names_b = _csv_files(a), _csv_files(b)
    for name in sorted(set(names_a) ^ set(names_b)):
        out.differences.append(f"{name}: only in {a if name in names_a else b}")
    for name in sorted(set(names_a) & set(names_b)):
        out.files.append(name)
        ra, rb = read_csv(a / name), read_csv(b / name)
        if len(ra) != len(rb):
            out.differences.append(f"{name}: {len(ra)} rows vs {len(rb)}")
            continue
        for k, (x, y) in enumerate(zip(ra, rb, strict=True), start=2):
            if x.keys() != y.keys():
                out.differences.append(f"{name}:{k}: different columns")
                continue
            for col in x:
                if col in TIMING_COLUMNS:
                    continue
                out.compared += 1
                if x[col] != y[col]:
                    out.differences.append(f"{name}:{k}: {col} {x[col]!r} vs {y[col]!r}")
    return out
