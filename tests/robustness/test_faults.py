"""Issue 23: faults a robot log meets (a full disk, SIGTERM), the folders vio-depth must never
take for its own (eval, report, staging), and the security notes of docs/safety.md.
"""

import errno
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vio_core.errors import InputError
from vio_core.npyfile import load_array
from vio_depth.disparity import FileDisparity
from vio_depth.experiments.tasks import local_ray_problem
from vio_depth.io import open_sequence
from vio_depth.io.marker import write_marker
from vio_depth.run import read_frames_jsonl, staging_path
from vio_depth.run.folder import JOURNAL_NAME, OutputFolder

ROOT = Path(__file__).resolve().parents[2]


def _depth_files(out: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted((out / "depth").glob("*.png"))}


# --------------------------------------------------------------------------- a full disk
@pytest.mark.parametrize("where", ["depth_png", "journal"])
def test_disk_full_mid_run_keeps_the_old_result_and_resumes(mini_street, tmp_path, cli, one_line, digest,
                                                            monkeypatch, where):
    """ENOSPC while writing frame 3 (a depth PNG, or its journal line): one line, exit 1, the
    old result in --out byte-identical, the partial run resumable; after space is freed,
    --resume gives the depth maps of an uninterrupted run."""
    import vio_depth.io.depth_png as depth_png

    seq = mini_street(6)
    out, reference = tmp_path / "out", tmp_path / "reference"
    assert cli("run", seq, "--out", out)[0] == 0
    assert cli("run", seq, "--out", reference, "--seed", 3)[0] == 0
    old = digest(out)
    calls = {"n": 0}
    if where == "depth_png":
        real = depth_png.write_bytes_atomic

        def full(path, data):
            calls["n"] += 1
            if calls["n"] >= 4:
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
            return real(path, data)

        monkeypatch.setattr(depth_png, "write_bytes_atomic", full)
    else:
        real = OutputFolder.append

        def full(self, record):
            calls["n"] += 1
            if calls["n"] >= 4:
                raise OSError(errno.ENOSPC, "No space left on device", str(self.journal))
            return real(self, record)

        monkeypatch.setattr(OutputFolder, "append", full)
    rc, _, err = cli("run", seq, "--out", out, "--overwrite", "--seed", 3)
    one_line(rc, err, "No space left on device", "the partial run is kept in", "--resume continues it")
    assert digest(out) == old
    assert (staging_path(out) / JOURNAL_NAME).is_file()
    monkeypatch.undo()  # space freed
    rc, _, err = cli("run", seq, "--out", out, "--resume", "--seed", 3)
    assert rc == 0, err
    assert _depth_files(out) == _depth_files(reference) and not staging_path(out).exists()


@pytest.fixture
def small_filesystem(tmp_path):
    """A 1.5 MiB tmpfs (needs root with CAP_SYS_ADMIN; skipped elsewhere)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1536k", "tmpfs", str(mount)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_disk_full_on_a_real_small_filesystem(mini_street, tmp_path, cli, one_line, small_filesystem):
    """The same on a real file system that fills up mid-run, then grows (remount)."""
    seq = mini_street(24)
    out = small_filesystem / "out"
    rc, _, err = cli("run", seq, "--out", out, "--uncertainty", "--save-npy")
    one_line(rc, err, "no space left on device", "--resume continues it") if "no space" in err else \
        one_line(rc, err, "No space left on device", "--resume continues it")
    assert not out.exists() and (staging_path(out) / JOURNAL_NAME).is_file()
    subprocess.run(["mount", "-o", "remount,size=64m", str(small_filesystem)], check=True)
    rc, _, err = cli("run", seq, "--out", out, "--uncertainty", "--save-npy", "--resume")
    assert rc == 0, err
    assert len(read_frames_jsonl(out / "frames.jsonl")[1]) == 24 and not staging_path(out).exists()


# --------------------------------------------------------------------------- SIGTERM
def test_sigterm_is_handled_like_ctrl_c(mini_street, tmp_path, cli, one_line):
    """`kill` (a process manager's stop) mid-run: one line naming SIGTERM, exit 130, the
    partial run kept; --resume finishes it."""
    seq = mini_street(30)
    out = tmp_path / "out"
    journal = staging_path(out) / JOURNAL_NAME
    proc = subprocess.Popen([sys.executable, "-m", "vio_depth.cli", "run", str(seq), "--out", str(out),
                             "--no-progress"], stderr=subprocess.PIPE, text=True, cwd=ROOT)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120 and proc.poll() is None:
        if journal.is_file() and len(journal.read_text().splitlines()) >= 4:  # header + 3 frames
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    one_line(proc.returncode, err, "interrupted (SIGTERM)", "--resume continues it", code=130)
    assert not out.exists() and journal.is_file()
    rc, _, err = cli("run", seq, "--out", out, "--resume")
    assert rc == 0, err
    assert len(read_frames_jsonl(out / "frames.jsonl")[1]) == 30


# --------------------------------------------------------------------------- folders vio-depth did not write
def test_eval_refuses_a_user_folder_a_run_folder_and_a_busy_one(short_clip, mini_street, tmp_path, cli, one_line, digest):
    import fcntl

    seq = mini_street(3)
    user = tmp_path / "user"
    user.mkdir()
    (user / "results.csv").write_text("mine\n")
    rc, _, err = cli("eval", seq, "--out", user)
    one_line(rc, err, "holds no vio-depth evaluation", "vio-depth-eval.json")
    run = tmp_path / "run"
    assert cli("run", seq, "--out", run, *short_clip)[0] == 0
    before = digest(run)
    rc, _, err = cli("eval", seq, "--out", run)
    one_line(rc, err, "holds a vio-depth run folder")
    assert digest(run) == before
    busy = tmp_path / "busy"
    busy.mkdir()
    write_marker(busy, "eval")
    fd = os.open(busy, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        rc, _, err = cli("eval", seq, "--out", busy)
        one_line(rc, err, "another vio-depth eval is writing it")
    finally:
        os.close(fd)
    rc, _, err = cli("eval", seq, "--out", tmp_path / "e", "--markdown", seq / "notes.md")
    one_line(rc, err, "--markdown", "lies inside the input")
    assert (user / "results.csv").read_text() == "mine\n"


def test_report_never_writes_into_a_folder_it_did_not_make(short_clip, mini_street, tmp_path, cli, one_line):
    """`report OUT --to DIR` replaced DIR/plots and DIR/thumbs."""
    pytest.importorskip("matplotlib")
    seq = mini_street(3)
    out = tmp_path / "o"
    assert cli("run", seq, "--out", out, *short_clip)[0] == 0
    docs = tmp_path / "Documents"
    (docs / "plots").mkdir(parents=True)
    (docs / "plots" / "holiday.png").write_bytes(b"png")
    rc, _, err = cli("report", out, "--to", docs)
    one_line(rc, err, "Documents", "holds no vio-depth report")
    assert (docs / "plots" / "holiday.png").read_bytes() == b"png"
    for _ in range(2):  # a report folder of its own is rewritten
        rc, _, err = cli("report", out, "--to", tmp_path / "r")
        assert rc == 0, err


RECORD_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-3, 10**6), st.floats(allow_nan=True),
                          st.text(max_size=12), st.lists(st.integers(), max_size=2),
                          st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    from vio_depth import Pipeline, PipelineSettings, run_sequence

    street = ROOT / "sample_sequences" / "street"
    if not (street / "sequence.json").is_file():
        pytest.skip("bundled street sample missing")
    out = tmp_path_factory.mktemp("fuzz") / "run"
    seq = open_sequence(street)
    run_sequence(seq, Pipeline(PipelineSettings(), sequence=seq), out,
                 __import__("vio_depth.run", fromlist=["RunSettings"]).RunSettings(max_frames=4), progress=False)
    return out


@settings(max_examples=int(os.environ.get("VIO_DEPTH_HYPOTHESIS_EXAMPLES", "12")), deadline=None,
          derandomize=not os.environ.get("VIO_DEPTH_HYPOTHESIS_RANDOM"),
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.sampled_from(["frame", "status", "stem", "reason", "backfilled", "alpha", "beta",
                                           "matches", "dense_metrics", "sigma_alpha", "fit_diagnostics"]),
                          RECORD_VALUES), min_size=1, max_size=4),
       st.sampled_from(["metrics", "point_accuracy", "frames_in_sequence", "disparity_kind", None]), RECORD_VALUES)
def test_report_on_damaged_records_is_a_report_or_one_line(finished_run, tmp_path_factory, capsys, changes,
                                                           metrics_key, metrics_value):
    """Any field of frames.jsonl / metrics.json replaced by any JSON value: a report (exit 0)
    or one line (exit 1), never a traceback; never a file outside the report folder. 12
    derandomised examples (0.75 s each: matplotlib); 500 random ones were run once
    (``VIO_DEPTH_HYPOTHESIS_RANDOM=1 VIO_DEPTH_HYPOTHESIS_EXAMPLES=500``)."""
    pytest.importorskip("matplotlib")
    import shutil

    from vio_depth.cli import main

    run = tmp_path_factory.mktemp("case") / "run"
    shutil.copytree(finished_run, run)
    lines = (run / "frames.jsonl").read_text().splitlines()
    recs = [json.loads(ln) for ln in lines]
    for i, (key, value) in enumerate(changes):
        recs[1 + i % (len(recs) - 1)][key] = value
    (run / "frames.jsonl").write_text("\n".join(json.dumps(r) for r in recs) + "\n")
    if metrics_key is not None and (run / "metrics.json").is_file():
        m = json.loads((run / "metrics.json").read_text())
        m[metrics_key] = metrics_value
        (run / "metrics.json").write_text(json.dumps(m))
    before = sorted(p for p in run.parent.rglob("*") if "report" not in p.parts)
    rc = main(["report", str(run), "--to", str(run / "report")])
    err = capsys.readouterr().err
    assert rc in (0, 1) and "Traceback" not in err
    if rc == 1:
        assert len(err.strip().splitlines()) == 1
    assert sorted(p for p in run.parent.rglob("*") if "report" not in p.parts) == before


def test_a_symlinked_staging_folder_is_refused(mini_street, tmp_path, cli, one_line):
    seq = mini_street(3)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("keep")
    staging_path(tmp_path / "out").symlink_to(elsewhere)
    rc, _, err = cli("run", seq, "--out", tmp_path / "out", "--overwrite")
    one_line(rc, err, "not a folder vio-depth made")
    assert (elsewhere / "keep.txt").read_text() == "keep"


def test_the_guard_sees_a_deleted_or_modified_user_file(tmp_path):
    """The guard of tests/conftest.py itself: user files count, vio-depth's folders do not."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_root_conftest", ROOT / "tests" / "conftest.py")
    guard = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(guard)
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "a.txt").write_text("a")
    (tmp_path / "run").mkdir()
    write_marker(tmp_path / "run", "run")
    (tmp_path / "run" / "depth.png").write_bytes(b"old")
    before = guard.snapshot(tmp_path)
    (tmp_path / "run" / "depth.png").write_bytes(b"new")
    assert guard.changed_user_files(before, guard.snapshot(tmp_path)) == []
    (tmp_path / "user" / "a.txt").write_text("b")
    assert guard.changed_user_files(before, guard.snapshot(tmp_path)) == [f"{tmp_path / 'user' / 'a.txt'}: modified"]


# --------------------------------------------------------------------------- security notes (docs/safety.md)
class _Payload:
    """Unpickling this would create a file: proof that code ran."""

    def __init__(self, target: str):
        self.target = target

    def __reduce__(self):
        return (open, (self.target, "w"))


def test_a_npy_with_a_pickle_payload_is_never_unpickled(tmp_path):
    seq_dir = tmp_path / "disp"
    seq_dir.mkdir()
    target = tmp_path / "pwned"
    arr = np.empty(1, dtype=object)
    arr[0] = _Payload(str(target))
    path = seq_dir / "000000.npy"
    np.save(path, arr, allow_pickle=True)
    assert pickle.dumps(arr[0])  # a real payload
    with pytest.raises(InputError, match="pickles are never loaded"):
        load_array(path, "disparity")
    with pytest.raises(InputError, match="pickles are never loaded"):
        FileDisparity(seq_dir)(open_sequence(ROOT / "sample_sequences" / "street")[0])
    assert not target.exists()


@pytest.mark.parametrize("path", ["/etc/hostname", "../outside.jpg", "images/../../outside.jpg"])
def test_image_paths_never_climb_out_of_the_sequence(mini_street, tmp_path, cli, one_line, path):
    seq = mini_street(3)
    text = (seq / "frames.txt").read_text().replace("images/000001.jpg", path)
    (seq / "frames.txt").write_text(text)
    rc, _, err = cli("run", seq, "--out", tmp_path / "o")
    line = one_line(rc, err, "frames.txt:2")
    assert "outside the sequence folder" in line or "must be a relative path" in line


@pytest.mark.parametrize("version, mode, open_", [("2.9.3", None, True), ("2.51.0", "token", True),
                                                  ("2.52.0", None, True), ("2.52.0", "token", False),
                                                  ("2.60.0", None, False), ("2.60.0", "disabled", True)])
def test_a_local_ray_instance_without_authentication_is_reported(version, mode, open_):
    assert bool(local_ray_problem(version, mode)) is open_


@pytest.mark.parametrize("name", ["../../outside/scene.json", "/etc/scene.json"])
def test_ddad_file_names_never_leave_the_dataset_folder(tmp_path, name):
    from vio_core.errors import SequenceFormatError
    from vio_depth.io.ddad import DGP_SPLITS, ddad_split_scenes

    ds = tmp_path / "ddad.json"
    ds.write_text(json.dumps({"scene_splits": {str(DGP_SPLITS["val"]): {"filenames": [name]}}}))
    with pytest.raises(SequenceFormatError, match="points outside the dataset folder"):
        ddad_split_scenes(ds, "val")
