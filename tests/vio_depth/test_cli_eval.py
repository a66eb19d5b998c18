"""`vio-depth eval` on the command line: a table on stdout, the files, one-line errors."""

from pathlib import Path

from vio_depth.cli import main

ROOT = Path(__file__).resolve().parents[2]
STREET = ROOT / "sample_sequences" / "street"


def test_eval_prints_the_table_and_writes_the_files(tmp_path, capsys):
    out = tmp_path / "ev"
    code = main(["eval", f"{STREET}@frames=4:7", "--out", str(out), "--variants", "oracle,fixed",
                 "--executor", "sequential", "--markdown", str(tmp_path / "doc" / "evaluation.md"), "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0
    assert "street             oracle" in printed and "SIMULATED" in printed
    assert (out / "results.csv").is_file() and (out / "eval.json").is_file()
    assert (tmp_path / "doc" / "evaluation" / "variants.png").is_file()
    assert "vio-depth eval" in (tmp_path / "doc" / "evaluation.md").read_text()


def test_eval_errors_are_one_line(tmp_path, capsys):
    assert main(["eval", str(STREET), "--out", str(tmp_path / "x"), "--variants", "ransac"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("vio-depth: error: unknown variant 'ransac'") and err.count("\n") == 1
    assert main(["eval", f"{STREET}@frames=400:500", "--out", str(tmp_path / "x")]) == 1
    assert "no frame" in capsys.readouterr().err
    assert main(["eval", "--out", str(tmp_path / "x")]) == 1
    assert "no sequence" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # nothing written before the options are checked
