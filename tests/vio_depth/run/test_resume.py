"""Issue 12, case 3: a killed run is continued with --resume, and the result equals an
uninterrupted run; a resume with other settings, another version or irreproducible
records is refused."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vio_depth.cli import main
from vio_depth.run import read_frames_jsonl, staging_path
from vio_depth.run.folder import JOURNAL_NAME

ROOT = Path(__file__).resolve().parents[3]
VOLATILE = ("seconds", "timings")


def _run(argv, capsys):
    # every run here is a few street frames, which get depth from SIFT's weak pairs only
    # (tests/conftest.py SHORT_CLIP); klt, the default with these poses, would end them in exit 3
    extra = ["--matcher", "sift"] if argv[0] == "run" and "--matcher" not in argv else []
    rc = main([str(a) for a in [*argv, *extra, "--no-progress"]])
    out, err = capsys.readouterr()
    return rc, out, err


def _journal_frames(out: Path) -> int:
    try:
        lines = (staging_path(out) / JOURNAL_NAME).read_bytes().split(b"\n")
    except OSError:
        return 0
    return sum(1 for ln in lines if b'"record": "frame"' in ln)


def _kill_after(argv, out: Path, frames: int, timeout: float = 240.0) -> None:
    """Start the CLI in a subprocess and SIGKILL it once ``frames`` frames are journaled."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "vio_depth.cli", *map(str, argv), "--no-progress"], cwd=ROOT,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    try:
        while _journal_frames(out) < frames:
            if proc.poll() is not None:
                pytest.fail(f"the run ended before it could be killed: {proc.stderr.read().decode()[-500:]}")
            if time.monotonic() - t0 > timeout:
                pytest.fail("the run did not journal frames in time")
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
    assert proc.returncode == -signal.SIGKILL


def _files(out: Path) -> dict:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name not in ("frames.jsonl", "metrics.json", "vio-depth-run.json") and "report" not in p.parts}


def _records(out: Path):
    header, frames = read_frames_jsonl(out / "frames.jsonl")
    header.pop("command")
    return header, [{k: v for k, v in f.items() if k not in VOLATILE} for f in frames]


def _metrics(out: Path):
    m = json.loads((out / "metrics.json").read_text())
    m.pop("seconds")
    m.pop("timings")
    m["run"].pop("command")
    return m


@pytest.mark.slow
def test_sigkilled_run_resumes_to_the_uninterrupted_result(mini_street, tmp_path, capsys):
    seq = mini_street(12)
    # klt, the default with these poses: its tracks carry state from frame to frame
    flags = ["--save-npy", "--save-ply", "sparse,dense:8", "--save-preview", "--uncertainty", "--matcher", "klt"]
    whole = tmp_path / "whole"
    assert _run(["run", seq, "--out", whole, *flags], capsys)[0] == 0

    out = tmp_path / "killed"
    _kill_after(["run", seq, "--out", out, *flags], out, frames=5)
    assert not out.exists()  # a killed run leaves --out untouched
    k = _journal_frames(out)
    assert 5 <= k < 12

    rc, table, err = _run(["run", seq, "--out", out, *flags, "--resume"], capsys)
    assert rc == 0, err
    assert not staging_path(out).exists() and not (out / JOURNAL_NAME).exists()
    assert _files(out) == _files(whole)  # every depth PNG, npy, PLY and preview byte-identical
    assert _records(out) == _records(whole)
    assert _metrics(out) == _metrics(whole)
    assert _records(out)[1][0].get("backfilled") is True  # the backward pass ran after the resume
    assert "metric depth for 12 of 12" in table


def test_resume_refuses_other_settings_and_another_version(mini_street, tmp_path, capsys):
    seq = mini_street(8)
    out = tmp_path / "out"
    bad = seq / "images" / "000005.jpg"
    good = bad.read_bytes()
    bad.write_bytes(good[:2000])
    rc, _, err = _run(["run", seq, "--out", out], capsys)
    assert rc == 1 and "--resume continues it" in err
    bad.write_bytes(good)

    rc, _, err = _run(["run", seq, "--out", out, "--resume", "--min-translation", "0.5"], capsys)
    assert rc == 1 and "cannot resume" in err and "settings.pairing.min_translation_m" in err
    assert len(err.strip().splitlines()) == 1

    journal = staging_path(out) / JOURNAL_NAME
    lines = journal.read_text().splitlines()
    header = json.loads(lines[0])
    header["vio_depth_version"] = "0.0.1"
    journal.write_text("\n".join([json.dumps(header), *lines[1:]]) + "\n")
    rc, _, err = _run(["run", seq, "--out", out, "--resume"], capsys)
    assert rc == 1 and "vio_depth_version: \"0.0.1\" before" in err

    header["vio_depth_version"] = json.loads(lines[0])["vio_depth_version"]
    journal.write_text("\n".join([json.dumps(header), *lines[1:]]) + "\n")
    rc, _, err = _run(["run", seq, "--out", out, "--resume"], capsys)
    assert rc == 0, err
    assert len(read_frames_jsonl(out / "frames.jsonl")[1]) == 8


def test_resume_refuses_when_a_replayed_frame_differs(mini_street, tmp_path, capsys):
    seq = mini_street(7)
    out = tmp_path / "out"
    bad = seq / "images" / "000005.jpg"
    good = bad.read_bytes()
    bad.write_bytes(good[:2000])
    assert _run(["run", seq, "--out", out], capsys)[0] == 1
    bad.write_bytes(good)
    journal = staging_path(out) / JOURNAL_NAME
    lines = journal.read_text().splitlines()
    rec = json.loads(lines[3])
    rec["alpha"] = rec["alpha"] * 1.5
    lines[3] = json.dumps(rec)
    journal.write_text("\n".join(lines) + "\n")
    rc, _, err = _run(["run", seq, "--out", out, "--resume"], capsys)
    assert rc == 1 and "replaying frame 2" in err and "alpha" in err
    assert not out.exists()


def test_a_torn_journal_line_is_dropped_and_the_frame_redone(mini_street, tmp_path, capsys):
    seq = mini_street(6)
    out = tmp_path / "out"
    bad = seq / "images" / "000004.jpg"
    good = bad.read_bytes()
    bad.write_bytes(good[:2000])
    assert _run(["run", seq, "--out", out], capsys)[0] == 1
    bad.write_bytes(good)
    journal = staging_path(out) / JOURNAL_NAME
    data = journal.read_bytes()
    journal.write_bytes(data[: len(data) - 40])  # a kill in the middle of the last line
    assert _run(["run", seq, "--out", out, "--resume"], capsys)[0] == 0
    assert [f["frame"] for f in read_frames_jsonl(out / "frames.jsonl")[1]] == list(range(6))


def test_resume_without_an_interrupted_run(mini_street, tmp_path, capsys):
    seq = mini_street(4)
    out = tmp_path / "out"
    rc, _, err = _run(["run", seq, "--out", out, "--resume"], capsys)  # nothing to resume: a fresh run
    assert rc == 0, err
    before = (out / "frames.jsonl").read_bytes()
    rc, table, _ = _run(["run", seq, "--out", out, "--resume"], capsys)
    assert rc == 0 and "nothing to resume" in table
    assert (out / "frames.jsonl").read_bytes() == before
    rc, _, err = _run(["run", seq, "--out", out, "--resume", "--max-frames", 2], capsys)
    assert rc == 1 and "different finished run" in err and "max_frames" in err
