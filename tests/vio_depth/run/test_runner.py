"""run_sequence and the run's records: header with version, command line and settings; typed
frame records; run settings; config files; the --points SFM regression."""

import json
import logging
from pathlib import Path

import pytest

from vio_core import SettingsError
from vio_depth import Pipeline, PipelineSettings, __version__, open_sequence, run_sequence
from vio_depth.cli import main
from vio_depth.run import RunSettings, config_from_dict, config_to_dict, dump_config, load_config, read_frames_jsonl

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"
needs_street = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled street sample missing")


@needs_street
def test_records_carry_version_command_settings_and_timings(tmp_path):
    seq = open_sequence(STREET)
    settings = PipelineSettings.from_presets(pairing="kitti")
    run = RunSettings(max_frames=4)
    summary = run_sequence(seq, Pipeline(settings, sequence=seq), tmp_path / "out", run, command=["my", "cmd"])
    header, frames = read_frames_jsonl(tmp_path / "out" / "frames.jsonl")
    assert header["vio_depth_version"] == __version__ and header["command"] == ["my", "cmd"]
    assert config_from_dict(header["settings"]) == (settings, run)  # the settings, complete
    assert header["disparity_kind"] == "simulated" and header["sequence"]["format"] == "native"
    assert [f["frame"] for f in frames] == [0, 1, 2, 3] and all(f["record"] == "frame" for f in frames)
    for f in frames:
        assert {"points", "disparity", "write", "evaluation", "load"} <= set(f["timings"])
        # a backfilled frame re-uses the features the forward pass extracted
        assert ("features" in f["timings"]) != bool(f.get("backfilled"))
        assert f["point_source"] == "sfm" and "alpha" in f  # core fields always present (null if none)
    assert frames[1]["fit_source"] == "frame" and frames[1]["fit_diagnostics"]["fit_status"] == "ok"
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["run"] == header and metrics["frames_processed"] == summary.frames_processed == 4


@needs_street
def test_points_source_name_in_any_case_is_the_same_run(tmp_path, capsys):
    """Regression: `--points SFM` skipped the backward pass and the point-accuracy report and
    named the metrics row "SFM", because the raw setting was compared with "sfm"."""
    rows = {}
    for name in ("sfm", "SFM"):
        out = tmp_path / name
        assert main(["run", str(STREET), "--out", str(out), "--max-frames", "5", "--points", name,
                     "--matcher", "sift"]) == 0  # 5 frames: SIFT's weak pairs (tests/conftest.py SHORT_CLIP)
        metrics = json.loads((out / "metrics.json").read_text())
        assert set(metrics["metrics"]) == {"sfm", "oracle"}
        assert metrics["point_accuracy"]["frames"] >= 4
        _, frames = read_frames_jsonl(out / "frames.jsonl")
        assert frames[0].get("backfilled") is True  # the offline backward pass ran
        rows[name] = [(f["status"], f["alpha"]) for f in frames]
    assert rows["sfm"] == rows["SFM"]
    assert "sfm " in capsys.readouterr().out


def test_run_settings_are_validated():
    with pytest.raises(SettingsError, match="max_frames"):
        RunSettings(max_frames=-1)
    with pytest.raises(SettingsError, match="min_eval_depth < max_eval_depth"):
        RunSettings(max_eval_depth=0.0)


def test_config_file_round_trip_and_errors(tmp_path):
    settings = PipelineSettings.from_presets(matcher="sift", pairing="indoor", rescaler="per_frame", points="lidar:8")
    run = RunSettings(max_frames=7, uncertainty=True, max_eval_depth=10.0)
    path = tmp_path / "c.toml"
    path.write_text(dump_config(settings, run))
    assert load_config(path) == (settings, run)
    assert config_from_dict(config_to_dict(settings, run)) == (settings, run)
    path.write_text("[pairing]\npreset = 'indoor'\nmin_translation_m = -1\n")
    with pytest.raises(SettingsError, match="c.toml: pairing: .*positive"):
        load_config(path)
    path.write_text("[run]\nmax_frame = 3\n")
    with pytest.raises(SettingsError, match=r"unknown setting run\.max_frame"):
        load_config(path)


def _dumped(flags: list[str], tmp_path, capsys):
    """The settings ``vio-depth config --dump FLAGS`` prints, read back (it must exit 0)."""
    assert main(["config", "--dump", *flags]) == 0
    dumped = tmp_path / "dumped.toml"
    dumped.write_text(capsys.readouterr().out)
    return load_config(dumped)


def test_cli_config_dump_applies_file_then_flags(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text("[pairing]\npreset = 'indoor'\n\n[run]\nmax_eval_depth = 10.0\n")
    settings, run = _dumped(["--config", str(path), "--min-translation", "0.4", "--seed", "5"], tmp_path, capsys)
    assert settings.pairing.min_translation_m == 0.4 and settings.pairing.min_rotation_deg == 5.0
    assert run.max_eval_depth == 10.0
    assert settings.rescaler.ransac.seed == settings.points.seed == settings.disparity.seed == 5


def test_cli_preset_flag_is_refined_by_the_file_and_a_disagreeing_preset_is_refused(tmp_path, capsys):
    """``--poses vio --config c.toml`` with ``[poses.backend]`` in the file: the file refines the
    flag's preset (it used to fail, the file being read against the default pose source, and a
    file naming the preset lost its tables to the flag's preset); a file naming another preset
    than the flag is one error line."""
    path = tmp_path / "c.toml"
    path.write_text("[poses.backend]\nkind = 'process'\n\n[matcher]\nmax_features = 1234\n")
    settings, _ = _dumped(["--config", str(path), "--poses", "vio", "--matcher", "sift"], tmp_path, capsys)
    assert settings.poses.backend.kind == "process" and settings.matcher.max_features == 1234
    path.write_text("[poses]\npreset = 'vio'\n")
    assert main(["config", "--dump", "--config", str(path), "--poses", "gt"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--poses gt" in err and "'vio'" in err


def test_library_is_silent_and_cli_verbosity_shows_log_records(tmp_path, capsys, caplog):
    assert any(isinstance(h, logging.NullHandler) for h in logging.getLogger("vio_depth").handlers)
    if not (STREET / "sequence.json").exists():
        pytest.skip("bundled street sample missing")
    assert main(["-v", "run", str(STREET), "--out", str(tmp_path / "o"), "--max-frames", "6", "--no-progress"]) == 0
    assert "INFO" in capsys.readouterr().err
    assert main(["-q", "run", str(STREET), "--out", str(tmp_path / "p"), "--max-frames", "6", "--no-progress"]) == 0
    assert capsys.readouterr().err == ""
