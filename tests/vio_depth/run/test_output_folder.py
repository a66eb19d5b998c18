"""Issue 12, cases 1, 2 and 4: output folders that cannot hurt (inputs, old results, odd paths).

Every case runs the real CLI on a small copy of the street sample and checks the exit
code, that stderr is one line without a traceback, and what is (not) on disk afterwards.
"""

import errno
import fcntl
import os
import shutil

import pytest

from vio_depth.cli import main
from vio_depth.io.depth_png import read_depth_png
from vio_depth.run import OutputFolder, OutputFolderError, read_frames_jsonl, staging_path
from vio_depth.run.folder import JOURNAL_NAME, replace_folder
from vio_depth.io.marker import write_marker


def _run(argv, capsys):
    # every run here is a few street frames, which get depth from SIFT's weak pairs only
    # (tests/conftest.py SHORT_CLIP); klt, the default with these poses, would end them in exit 3
    extra = ["--matcher", "sift"] if argv[0] == "run" else []
    rc = main([str(a) for a in [*argv, *extra, "--no-progress"]])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line(rc, err, *fragments, code=1):
    assert rc == code, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("vio-depth: error:") and "Traceback" not in err
    for f in fragments:
        assert f in lines[0], lines[0]


# --------------------------------------------------------------------------- case 1: inputs
def test_out_equal_to_the_input_sequence_is_refused_and_the_input_untouched(mini_street, digest, capsys):
    """Issue 12 case 1: `--out SEQ` exited 0 after overwriting the input's ground-truth depth."""
    seq = mini_street(6)
    before = digest(seq)
    rc, _, err = _run(["run", seq, "--out", seq, "--max-frames", 4], capsys)
    _one_line(rc, err, "is the input", "never writes into its inputs")
    assert digest(seq) == before
    rc, _, err = _run(["run", seq, "--out", seq, "--max-frames", 4, "--overwrite"], capsys)
    _one_line(rc, err, "is the input")
    assert digest(seq) == before


@pytest.mark.parametrize("where", ["inside", "parent", "symlink"])
def test_out_inside_containing_or_linked_to_an_input_is_refused(mini_street, digest, tmp_path, capsys, where):
    seq = mini_street(4)
    before = digest(seq)
    out = {"inside": seq / "depth" / "out", "parent": tmp_path, "symlink": tmp_path / "link"}[where]
    if where == "symlink":
        out.symlink_to(seq)
    rc, _, err = _run(["run", seq, "--out", out, "--max-frames", 3, "--overwrite"], capsys)
    _one_line(rc, err, "input")
    assert digest(seq) == before
    assert not staging_path(out).exists()


def test_out_inside_the_disparity_folder_is_refused(mini_street, tmp_path, capsys):
    seq = mini_street(4)
    disp = tmp_path / "disp"
    disp.mkdir()
    rc, _, err = _run(["run", seq, "--out", disp / "o", "--disparity-dir", disp], capsys)
    _one_line(rc, err, "lies inside the input", str(disp))
    assert not (disp / "o").exists()


# --------------------------------------------------------------------------- case 2: old results
def test_a_finished_run_is_never_overwritten_without_overwrite(mini_street, digest, tmp_path, capsys):
    seq = mini_street(6)
    out = tmp_path / "out"
    assert _run(["run", seq, "--out", out, "--max-frames", 6], capsys)[0] == 0
    before = digest(out)
    rc, _, err = _run(["run", seq, "--out", out, "--max-frames", 3], capsys)
    _one_line(rc, err, "already holds a vio-depth run", "--overwrite", "--resume")
    assert digest(out) == before


def test_a_failing_run_with_overwrite_leaves_the_old_result_whole(mini_street, digest, tmp_path, capsys):
    """Issue 12 case 2: a run that failed at frame 10 overwrote depth/000002-9.png of a good
    result while the old frames.jsonl and metrics.json stayed."""
    seq = mini_street(8)
    out = tmp_path / "out"
    assert _run(["run", seq, "--out", out], capsys)[0] == 0
    before = digest(out)
    bad = seq / "images" / "000005.jpg"
    bad.write_bytes(bad.read_bytes()[:2000])
    rc, _, err = _run(["run", seq, "--out", out, "--overwrite", "--seed", 3], capsys)
    _one_line(rc, err, "000005.jpg", "--resume continues it")
    assert digest(out) == before  # not one byte of the old result changed
    assert (staging_path(out) / JOURNAL_NAME).is_file()  # the partial run waits for --resume


def test_overwrite_with_fewer_frames_leaves_no_stale_files(mini_street, tmp_path, capsys):
    """Issue 12 case 2: `--max-frames 20` into a 130-frame result left 110 stale PNGs."""
    seq = mini_street(8)
    out = tmp_path / "out"
    assert _run(["run", seq, "--out", out, "--save-npy"], capsys)[0] == 0
    assert len(list((out / "depth").glob("*.png"))) == 8
    assert _run(["run", seq, "--out", out, "--max-frames", 3, "--overwrite"], capsys)[0] == 0
    _, frames = read_frames_jsonl(out / "frames.jsonl")
    assert sorted(p.stem for p in (out / "depth").glob("*.png")) == [f["stem"] for f in frames if f["alpha"]]
    assert len(frames) == 3 and not (out / "depth_npy").exists()
    assert not staging_path(out).exists()
    assert not [p for p in tmp_path.iterdir() if "vio-depth" in p.name]


def test_a_mid_run_failure_writes_nothing_into_out(mini_street, tmp_path, capsys):
    """Issue 12 case 2: every mid-run failure left the PNGs written so far in --out."""
    seq = mini_street(8)
    bad = seq / "images" / "000004.jpg"
    bad.write_bytes(bad.read_bytes()[:2000])
    out = tmp_path / "out"
    rc, _, err = _run(["run", seq, "--out", out], capsys)
    _one_line(rc, err, "000004.jpg", "truncated JPEG")
    assert not out.exists()
    written = sorted(p.name for p in (staging_path(out) / "depth").glob("*.png"))
    assert written and max(written) < "000004.png"
    # without --resume or --overwrite a new run refuses to discard the partial one
    rc, _, err = _run(["run", seq, "--out", out], capsys)
    _one_line(rc, err, "interrupted run", "--resume", "--overwrite")
    # --overwrite discards it and starts over
    shutil.copy(seq / "images" / "000003.jpg", bad)
    assert _run(["run", seq, "--out", out, "--overwrite", "--max-frames", 5], capsys)[0] == 0
    assert len(read_frames_jsonl(out / "frames.jsonl")[1]) == 5 and not staging_path(out).exists()


def test_a_non_empty_folder_that_is_no_run_is_never_replaced(mini_street, tmp_path, capsys):
    seq = mini_street(4)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    for flag in ([], ["--overwrite"], ["--resume"]):
        rc, _, err = _run(["run", seq, "--out", out, *flag], capsys)
        _one_line(rc, err, "holds no vio-depth run")
        assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_an_empty_existing_folder_is_used(mini_street, tmp_path, capsys):
    seq = mini_street(4)
    out = tmp_path / "empty"
    out.mkdir()
    assert _run(["run", seq, "--out", out], capsys)[0] == 0
    assert len(read_frames_jsonl(out / "frames.jsonl")[1]) == 4


def test_a_locked_staging_folder_means_another_run_is_writing(mini_street, tmp_path, capsys):
    seq = mini_street(4)
    out = tmp_path / "out"
    staging = staging_path(out)
    staging.mkdir()
    write_marker(staging, "run")
    (staging / JOURNAL_NAME).write_text("")
    fd = os.open(staging, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        for flag in ([], ["--overwrite"], ["--resume"]):  # issue 23: never "--resume" while it works
            rc, _, err = _run(["run", seq, "--out", out, *flag], capsys)
            _one_line(rc, err, "another vio-depth run is writing it")
            assert "--resume" not in err
    finally:
        os.close(fd)
    assert staging.is_dir() and not out.exists()


# --------------------------------------------------------------------------- case 4: odd --out paths
def test_out_that_is_a_file_is_one_line(mini_street, tmp_path, capsys):
    seq = mini_street(3)
    f = tmp_path / "file.txt"
    f.write_text("x")
    rc, _, err = _run(["run", seq, "--out", f], capsys)
    _one_line(rc, err, "is not a folder")
    assert f.read_text() == "x"
    rc, _, err = _run(["run", seq, "--out", f / "sub"], capsys)
    _one_line(rc, err, "sub")


def test_out_with_too_long_a_name_is_one_line(mini_street, tmp_path, capsys):
    seq = mini_street(3)
    rc, _, err = _run(["run", seq, "--out", tmp_path / ("a" * 300)], capsys)
    _one_line(rc, err, "name too long")
    # a name that fits but whose staging name would not still works
    out = tmp_path / ("b" * 250)
    assert _run(["run", seq, "--out", out], capsys)[0] == 0
    assert (out / "frames.jsonl").is_file() and len(staging_path(out).name.encode()) <= 255


@pytest.mark.parametrize("where", ["/proc/vio-depth-test/out", "/sys/vio-depth-test", "/dev/vio-depth-test"])
def test_out_under_a_kernel_file_system_is_one_line(mini_street, capsys, where):
    seq = mini_street(3)
    rc, _, err = _run(["run", seq, "--out", where], capsys)
    _one_line(rc, err, "kernel file system")


def test_unwritable_out_parent_is_one_line(mini_street, tmp_path, capsys, monkeypatch):
    """The staging folder cannot be created (EACCES, as for a folder the user may not write)."""
    seq = mini_street(3)
    real_mkdir = os.mkdir

    def deny(path, *args, **kwargs):
        if "vio-depth-partial" in os.fsdecode(path):
            raise PermissionError(errno.EACCES, "Permission denied", os.fsdecode(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", deny)
    rc, _, err = _run(["run", seq, "--out", tmp_path / "ro" / "out"], capsys)
    _one_line(rc, err, "permission denied")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_unwritable_out_parent_for_real_is_one_line(mini_street, tmp_path, capsys):
    seq = mini_street(3)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        rc, _, err = _run(["run", seq, "--out", ro / "out"], capsys)
        _one_line(rc, err, "permission denied")
    finally:
        ro.chmod(0o755)


# --------------------------------------------------------------------------- the swap
def test_replace_folder_swaps_and_removes_the_old(tmp_path):
    new, target = tmp_path / "new", tmp_path / "target"
    new.mkdir()
    (new / "a").write_text("new")
    target.mkdir()
    (target / "b").write_text("old")
    ident = write_marker(target, "run")
    replace_folder(new, target, ident)
    assert [p.name for p in target.iterdir()] == ["a"] and not new.exists()


def test_replace_folder_never_deletes_what_it_did_not_check(tmp_path):
    """Issue 23: the old content is deleted only when it still carries the marker id read
    before the run; anything else is swapped back, untouched."""
    new, target = tmp_path / "new", tmp_path / "target"
    new.mkdir()
    (new / "a").write_text("new")
    target.mkdir()
    (target / "b").write_text("user file")
    write_marker(target, "run")  # another run's id
    with pytest.raises(OSError, match="changed while the run was working"):
        replace_folder(new, target, "0" * 32)
    assert (target / "b").read_text() == "user file" and (new / "a").read_text() == "new"


def test_staging_without_journal_is_a_leftover_and_is_removed(tmp_path):
    out = tmp_path / "out"
    staging = staging_path(out)
    staging.mkdir()
    write_marker(staging, "run")
    (staging / "old.png").write_bytes(b"x")
    folder = OutputFolder(out)
    assert folder.interrupted() is False and not staging.exists()


def test_a_staging_name_without_marker_is_never_deleted(tmp_path):
    """Issue 23, case 1: a folder with the staging name but no marker is refused, not removed."""
    out = tmp_path / "out"
    staging = staging_path(out)
    staging.mkdir()
    (staging / "photo.jpg").write_bytes(b"x")
    with pytest.raises(OutputFolderError, match="carries no vio-depth marker"):
        OutputFolder(out).interrupted()
    assert (staging / "photo.jpg").read_bytes() == b"x"


def test_output_folder_refuses_a_dot_name(tmp_path):
    with pytest.raises(OutputFolderError):
        OutputFolder("/")


def test_depth_is_readable_after_the_swap(mini_street, tmp_path, capsys):
    seq = mini_street(3)
    out = tmp_path / "out"
    assert _run(["run", seq, "--out", out], capsys)[0] == 0
    for p in (out / "depth").glob("*.png"):
        assert read_depth_png(p).max() > 0


def test_the_report_names_out_not_the_staging_folder(mini_street, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    seq = mini_street(3)
    out = tmp_path / "myrun"
    rc, table, err = _run(["run", seq, "--out", out, "--report"], capsys)
    assert rc == 0, err
    assert f"report: {out / 'report' / 'index.html'}" in table
    for page in [p for p in (out / "report").glob("*.*") if p.suffix in (".html", ".md")]:
        text = page.read_text(encoding="utf-8", errors="replace")
        assert "vio-depth-partial" not in text and "myrun" in text
