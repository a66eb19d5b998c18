"""CLI: the optional-output flags fail early with one clear line, before anything is written."""

from pathlib import Path

import pytest

from vio_depth.cli import main

ROOT = Path(__file__).resolve().parents[2]
STREET = ROOT / "sample_sequences" / "street"
pytestmark = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled street sample missing")


@pytest.mark.parametrize("flags, fragment", [
    (["--save-ply", "mesh"], "unknown item 'mesh'"),
    (["--save-ply", "dense:0"], "stride"),
    (["--ply-frames", "1,2"], "add --save-ply dense"),
    (["--save-ply", "sparse", "--ply-frames", "1,2"], "dense"),
    (["--save-preview", "--preview-range", "9:3"], "0 < MIN < MAX"),
    (["--save-preview", "--preview-colormap", "jet"], "turbo"),
])
def test_bad_output_flags_give_one_line_and_write_nothing(tmp_path, capsys, flags, fragment):
    out = tmp_path / "out"
    rc = main(["run", str(STREET), "--out", str(out), "--max-frames", "2", *flags])
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert rc == 1 and len(lines) == 1 and lines[0].startswith("vio-depth: error:") and fragment in lines[0]
    assert not out.exists()


def test_report_without_matplotlib_says_how_to_install(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else real(name, *a))
    rc = main(["run", str(STREET), "--out", str(tmp_path / "out"), "--max-frames", "2", "--report"])
    err = capsys.readouterr().err
    assert rc == 1 and "matplotlib" in err and ".[report]" in err
    assert not (tmp_path / "out").exists()
