"""A named baseline revision of this repository, checked out for a benchmark run.

Benchmarks that compare against a baseline *in the same run* (``bench_trust.py``,
``compare_outputs.py``) run the baseline's code from a temporary, detached git worktree
(in a subprocess with ``PYTHONPATH`` set to it and this checkout's virtual environment).
"""

from __future__ import annotations

import contextlib
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def baseline_checkout(rev: str, where: Path):
    """Check ``rev`` out at ``where`` (a path that does not exist yet), yield ``where``, and
    remove the worktree afterwards, whatever happened."""
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-f", str(where), rev],
                   check=True, capture_output=True)
    try:
        yield where
    finally:
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(where)], capture_output=True)
