"""CLI: end-to-end on a short slice of the bundled street sample, and bad input handling."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vio_depth.cli import main
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.run import read_frames_jsonl, staging_path

ROOT = Path(__file__).resolve().parents[2]
STREET = ROOT / "sample_sequences" / "street"


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _assert_one_line_error(rc, err, *fragments):
    assert rc == 1
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("vio-depth: error:")
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0]


def test_missing_sequence_folder_is_one_clear_line(tmp_path, capsys):
    rc, _, err = _run(["run", tmp_path / "nope", "--out", tmp_path / "out"], capsys)
    _assert_one_line_error(rc, err, "nope")
    assert not (tmp_path / "out" / "frames.jsonl").exists()


def test_folder_that_is_no_sequence_is_rejected(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    rc, _, err = _run(["run", tmp_path / "empty", "--out", tmp_path / "out"], capsys)
    _assert_one_line_error(rc, err, "not a recognised sequence")


@pytest.mark.parametrize("option, value, listed", [
    ("--matcher", "surf", "sift"),
    ("--pairing", "mars", "kitti"),
    ("--poses", "gps", "gt"),
    ("--points", "radar:3", "lidar"),
])
def test_unknown_names_list_valid_ones(tmp_path, capsys, option, value, listed):
    rc, _, err = _run(["run", STREET, "--out", tmp_path / "out", option, value, "--max-frames", 2], capsys)
    _assert_one_line_error(rc, err, value, listed)


needs_street = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled street sample missing")


@needs_street
def test_disparity_dir_with_wrong_shape_fails_cleanly_without_outputs(tmp_path, capsys):
    from vio_depth.io import open_sequence

    seq = open_sequence(STREET)
    ddir = tmp_path / "disp"
    ddir.mkdir()
    np.save(ddir / f"{seq[0].stem}.npy", np.ones((10, 10), np.float32))
    out = tmp_path / "out"
    rc, _, err = _run(["run", STREET, "--out", out, "--disparity-dir", ddir, "--max-frames", 3], capsys)
    _assert_one_line_error(rc, err, f"{seq[0].stem}.npy", "disparity must be")
    leftovers = [p for p in out.rglob("*") if p.is_file()] if out.exists() else []
    assert leftovers == []


@needs_street
@pytest.mark.slow
def test_end_to_end_short_slice_and_affine_invariance(tmp_path, capsys):
    """Metric depth on 14 frames; an affinely transformed disparity gives the same depth."""
    from vio_depth.io import open_sequence
    from vio_depth.io.depth_png import read_depth_png

    n = 14
    out = tmp_path / "own"
    rc, table, err = _run(["run", STREET, "--out", out, "--max-frames", n, "--seed", 1], capsys)
    assert rc == 0, err
    assert "sfm" in table and "oracle" in table and "SIMULATED" in table
    header, rows = read_frames_jsonl(out / "frames.jsonl")
    assert header["record"] == "run" and header["command"][:2] == ["vio-depth", "run"]
    assert [r["frame"] for r in rows] == list(range(n))
    for key in ("partner_keyframe", "matches", "triangulated_points", "inliers", "alpha", "beta", "r2",
                "status", "seconds"):
        assert key in rows[0]
    with_depth = [r for r in rows if r["alpha"] is not None]
    assert len(with_depth) >= n - 2  # only the first frame(s) may lack a pair
    metrics = json.loads((out / "metrics.json").read_text())
    sfm, oracle = metrics["metrics"]["sfm"], metrics["metrics"]["oracle"]
    assert sfm["n_frames"] == len(with_depth)
    assert sfm["delta1"] >= oracle["delta1"] - 0.05
    assert sfm["abs_rel"] <= 1.5 * oracle["abs_rel"]
    pngs = sorted((out / "depth").glob("*.png"))
    assert len(pngs) == len(with_depth)
    assert not list(out.rglob("*.partial"))

    # The same run on disparity' = 3 d + 0.5 (still affine-invariant) gives the same metric depth.
    seq = open_sequence(STREET)
    own = create_disparity_source(DisparitySettings(), seq)
    ddir = tmp_path / "affine"
    ddir.mkdir()
    for i in range(n):
        np.save(ddir / f"{seq[i].stem}.npy", (3.0 * own(seq[i]) + 0.5).astype(np.float32))
    out2 = tmp_path / "affine_out"
    rc, _, err = _run(["run", STREET, "--out", out2, "--max-frames", n, "--seed", 1, "--disparity-dir", ddir], capsys)
    assert rc == 0, err
    a = read_depth_png(pngs[-1])
    b = read_depth_png(out2 / "depth" / pngs[-1].name)
    valid = (a > 0) & (b > 0)
    assert valid.mean() > 0.5
    assert np.median(np.abs(a[valid] - b[valid]) / a[valid]) < 0.01


def test_console_script_reports_errors_without_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "vio_depth.cli", "run", str(tmp_path / "missing"),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.startswith("vio-depth: error:") and "Traceback" not in proc.stderr


@needs_street
def test_reference_lidar_points_are_a_named_row(tmp_path, capsys):
    out = tmp_path / "lidar"
    rc, table, err = _run(["run", STREET, "--out", out, "--points", "lidar:8", "--max-frames", 3,
                           "--uncertainty"], capsys)
    assert rc == 0, err
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert set(metrics) == {"lidar:8", "oracle"}
    assert metrics["lidar:8"]["n_frames"] == 3  # reference points exist from the first frame on
    assert "lidar:8" in table and "triangulated points vs ground truth" not in table
    assert len(list((out / "uncertainty").glob("*.png"))) == 3


@needs_street
def test_unreadable_image_mid_run_is_one_line_and_leaves_only_complete_files(tmp_path, capsys):
    """Regression: a truncated JPEG made libjpeg print its own warning and decode grey;
    outputs were created with mode 0600 by the atomic writer."""
    import os
    import shutil
    import stat

    seq_dir = tmp_path / "street"
    shutil.copytree(STREET, seq_dir)
    bad = seq_dir / "images" / "000005.jpg"
    bad.write_bytes(bad.read_bytes()[:2000])
    out = tmp_path / "out"
    rc, _, err = _run(["run", seq_dir, "--out", out, "--max-frames", 8], capsys)
    _assert_one_line_error(rc, err, "000005.jpg", "truncated JPEG")
    assert not out.exists()  # --out is untouched; the partial run waits in the staging folder
    staging = staging_path(out)
    assert not list(staging.rglob("*.partial"))
    written = sorted(p.name for p in (staging / "depth").glob("*.png"))
    assert written and max(written) < "000005.png"  # frames before the bad one, each complete
    umask = os.umask(0)
    os.umask(umask)
    for p in (staging / "depth").glob("*.png"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask


@needs_street
def test_offline_backfill_gives_the_first_frame_depth_from_a_later_keyframe(tmp_path, capsys):
    rows = {}
    for flag in ([], ["--no-backfill"]):
        out = tmp_path / ("plain" if flag else "backfill")
        rc, _, err = _run(["run", STREET, "--out", out, "--max-frames", 6, "--matcher", "sift", *flag], capsys)
        assert rc == 0, err
        rows[bool(flag)] = read_frames_jsonl(out / "frames.jsonl")[1]
    streaming, offline = rows[True][0], rows[False][0]
    assert streaming["status"] == "no_pair" and streaming["alpha"] is None
    assert offline["status"] == "ok" and offline["backfilled"] is True
    assert offline["partner_keyframe"] > 0  # a later frame
    assert offline["abs_rel"] < 0.1
    # frames that had depth in the forward pass are untouched; a frame refused there may be
    # filled from a later pair, and says so
    for fwd, off in zip(rows[True][1:], rows[False][1:]):
        if fwd["alpha"] is not None:
            assert off["alpha"] == fwd["alpha"] and not off.get("backfilled")
        elif off["alpha"] is not None:
            assert off["backfilled"] is True


def test_guided_matching_flag_turns_it_on_for_sift_only(capsys):
    assert main(["config", "--dump", "--poses", "vio_offline"]) == 0
    assert "[matcher.guided]\nenabled = false" in capsys.readouterr().out  # sift's, off by default
    assert main(["config", "--dump", "--guided-matching"]) == 0  # sift when nothing names a matcher
    out = capsys.readouterr().out
    assert "[matcher.guided]\nenabled = true" in out and 'preset = "sift"' in out
    assert main(["config", "--dump", "--guided-matching", "--matcher", "disk+lightglue"]) == 1
    assert "--guided-matching needs a nearest-neighbour matcher (sift)" in capsys.readouterr().err


def test_presets_mark_the_matcher_each_pose_source_brings(capsys):
    assert main(["presets"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("  ")}
    assert lines["klt"].endswith("(default with --poses gt, vio, vio_realtime)")
    assert lines["sift"].endswith("(default with --poses imu, imu_real_mav, vio_offline)")
    assert lines["gt"].endswith("(default)") and "default" not in lines["disk+lightglue"]


def test_klt_matcher_and_edge_guard_flags(capsys):
    assert main(["config", "--dump", "--matcher", "klt", "--edge-guard", "0.1"]) == 0
    out = capsys.readouterr().out
    assert 'preset = "klt"' in out and "max_tracks = 500" in out
    assert "max_disparity_spread = 0.1" in out
    assert main(["config", "--dump", "--edge-guard", "0"]) == 1  # a guard must be positive
    assert "max_disparity_spread" in capsys.readouterr().err
    assert main(["config", "--dump", "--matcher", "klt", "--guided-matching"]) == 1  # tracks need no band


@needs_street
def test_offline_backfill_with_klt_tracks_the_frames_backwards(tmp_path, capsys):
    """The forward pass's KLT features carry forward track ids; the backward pass follows the
    frames backwards itself (with the kept forward features it paired nothing beyond them)."""
    out = tmp_path / "klt"
    rc, _, err = _run(["run", STREET, "--out", out, "--max-frames", 6, "--matcher", "klt", "--edge-guard", "0.1"],
                      capsys)
    assert rc == 0, err
    first = read_frames_jsonl(out / "frames.jsonl")[1][0]
    assert first["status"] == "ok" and first["backfilled"] is True
    assert first["partner_keyframe"] > 0 and first["abs_rel"] < 0.1
