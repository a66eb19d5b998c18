"""The marker file by which vio-depth recognises the folders it wrote (issue 23).

vio-depth replaces or deletes a folder only when it carries vio-depth's marker: a small
JSON file that only vio-depth writes, **first**, into every folder it creates for a run
(``vio-depth-run.json``, in the staging folder before anything else, so it travels with the
result into ``--out``), an evaluation (``vio-depth-eval.json``) or a report
(``vio-depth-report.json``)::

    {"vio_depth": "run", "marker_version": 1, "version": "0.2.0",
     "id": "5f0c...32 hex digits", "created": "2026-12-02T10:11:12Z"}

The random ``id`` names one run: before the old content of ``--out`` is deleted after the
atomic swap, its marker must still carry the id read when the run started, so a folder
swapped in behind vio-depth's back is never deleted.

Before (vio-depth 0.2.0 and earlier) a folder counted as a run when its ``frames.jsonl``
began with a JSON object holding a ``"frame"`` key: another tool's ``frames.jsonl`` made
a user's folder look like a run and ``--overwrite`` deleted it (issue 23, case 2). Runs
written by those versions carry no marker and are never replaced or deleted; delete them
yourself or choose another ``--out``.
"""

from __future__ import annotations

import json
import os
import re
import stat
import uuid
from datetime import datetime, timezone
from pathlib import Path

from .._version import __version__
from .depth_png import write_bytes_atomic

#: marker file of a run folder (and of its staging folder)
RUN_MARKER = "vio-depth-run.json"
#: marker file of an evaluation folder (``vio-depth eval --out``)
EVAL_MARKER = "vio-depth-eval.json"
#: marker file of a report folder (``vio-depth report --to``, ``OUT/report``)
REPORT_MARKER = "vio-depth-report.json"
MARKER_VERSION = 1
_NAMES = {"run": RUN_MARKER, "eval": EVAL_MARKER, "report": REPORT_MARKER}
_ID = re.compile(r"[0-9a-f]{32}")
#: a marker is a few hundred bytes; anything larger is not one
_MAX_MARKER_BYTES = 4096


def marker_name(kind: str) -> str:
    """The marker file name of ``kind`` (``"run"`` or ``"eval"``)."""
    if kind not in _NAMES:
        raise ValueError(f"marker kind must be one of {sorted(_NAMES)}, got {kind!r}")
    return _NAMES[kind]


def write_marker(folder, kind: str) -> str:
    """Write the ``kind`` marker into ``folder`` (atomically) and return its new random id."""
    ident = uuid.uuid4().hex
    body = {"vio_depth": kind, "marker_version": MARKER_VERSION, "version": __version__, "id": ident,
            "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
    write_bytes_atomic(Path(folder) / marker_name(kind), (json.dumps(body) + "\n").encode())
    return ident


def read_marker(folder, kind: str) -> str | None:
    """The id of ``folder``'s ``kind`` marker, or None when it carries none: the marker must
    be a regular file (not a link) of at most 4 KiB holding a JSON object with
    ``"vio_depth": kind`` and a 32-hex-digit ``id``."""
    path = Path(folder) / marker_name(kind)
    try:
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_MARKER_BYTES:
            return None
        body = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    if not isinstance(body, dict) or body.get("vio_depth") != kind:
        return None
    ident = body.get("id")
    return ident if isinstance(ident, str) and _ID.fullmatch(ident) else None


__all__ = ["EVAL_MARKER", "REPORT_MARKER", "RUN_MARKER", "marker_name", "read_marker", "write_marker"]
