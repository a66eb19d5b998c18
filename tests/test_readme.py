"""The README's Python example runs as written (from the repository root) and streams depth;
its test command is the one CI runs."""

import contextlib
import io
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_example_streams_metric_depth():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "README.md has no python example"
    if not (ROOT / "sample_sequences" / "room" / "sequence.json").exists():
        pytest.skip("bundled room sample missing")
    out = io.StringIO()
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)
        with contextlib.redirect_stdout(out):
            exec(compile(blocks[0], "README.md", "exec"), {})
    finally:
        os.chdir(cwd)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 8  # most of the 12 frames get metric depth
    depths = [float(re.search(r"median depth ([0-9.]+) m", line).group(1)) for line in lines]
    assert all(0.5 < d < 7.0 for d in depths)  # the room's depths: 0.5-6.8 m


def test_ci_runs_the_readme_test_command():
    """`.ci/run` runs README's command 2 (the suite's options: two processes, heavy checks left out)."""
    text = (ROOT / "README.md").read_text()
    found = re.search(r"# 2\. run the tests\n\./setup\.sh && (\.venv/bin/python -m pytest[^\n]*)\n", text)
    assert found, "README.md lost its test command"
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert found.group(1) in [line.strip() for line in ci], (found.group(1), ci)
