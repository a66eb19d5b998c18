"""Fixtures of the robustness suite: a CLI runner (small copies of the street sample,
``mini_street``, come from ``tests/conftest.py``).

Every in-process ``vio-depth`` command of this suite is guarded by ``tests/conftest.py``:
no file that existed before the command and was not vio-depth's may change.
"""

import pytest

from vio_depth.cli import main


@pytest.fixture
def cli(capsys):
    """``cli(*argv) -> (exit code, stdout, stderr)`` of an in-process ``vio-depth`` command."""

    def run(*argv, progress: bool = False):
        extra = ["--no-progress"] if not progress and argv and argv[0] in ("run", "eval") else []
        rc = main([str(a) for a in [*argv, *extra]])
        out, err = capsys.readouterr()
        return rc, out, err

    return run


def _one_line(rc, err, *fragments, code=1) -> str:
    """Assert exit ``code`` and exactly one stderr line, without traceback, holding ``fragments``."""
    assert rc == code, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "[ WARN" not in err and "[ERROR" not in err
    for f in fragments:
        assert f in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def one_line():
    """``one_line(rc, err, *fragments, code=1)``: exit ``code`` and exactly one stderr line,
    without a traceback or OpenCV log text, holding every fragment; returns the line."""
    return _one_line
