"""--calibrate-poses in a run: skipped (with the reason in metrics.json) for exact poses, for
--calibrate-poses off and for pose sources other than the sequence's; estimated on tracked
poses; an applied calibration gives the run frames with corrected poses."""

import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from vio_core import SettingsError
from vio_depth import Pipeline, PipelineSettings, open_sequence
from vio_depth.cli import main
from vio_depth.frame import Frame
from vio_depth.io import Sequence
from vio_depth.poses import GroundTruthPoses, PoseCalibration
from vio_depth.run import (
    PoseCalibratedSequence,
    RunSettings,
    RunSummary,
    calibrate_run_poses,
    format_table,
    read_frames_jsonl,
)
from vio_depth.run.pose_calibration import calibrated_sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "poses"))  # the calibration tests' scene
from calibration_scene import CAM, TRUE_DT, TRUE_T_B_C, IdMatcher, rotation_error_deg, scene  # noqa: E402

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"
needs_street = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled street sample missing")


class _Tracked(Sequence):
    """The synthetic scene of the calibration tests as a sequence whose poses are a body's (mocap)."""

    pose_kind = "mocap"

    def __init__(self, ts, T_w_b):
        super().__init__(Path("/synthetic"), "synthetic", CAM)
        self.ts, self.T_w_b = ts, T_w_b

    def __len__(self):
        return len(self.ts)

    @property
    def has_gt_depth(self):
        return False

    def frame(self, index):
        return Frame(index, float(self.ts[index]), f"{index:04d}", CAM, self.T_w_b[index],
                     load_image=lambda i=index: np.full((2, 2, 3), i, np.uint8))


@needs_street
def test_exact_poses_are_not_calibrated_and_the_run_says_why(tmp_path, capsys):
    records = {}
    for mode, reason in (("auto", "exact poses"), ("off", "--calibrate-poses off")):
        out = tmp_path / mode
        assert main(["run", str(STREET), "--out", str(out), "--max-frames", "3", "--calibrate-poses", mode,
                     "--matcher", "sift"]) == 0  # 3 frames: SIFT's weak pairs (tests/conftest.py SHORT_CLIP)
        metrics = json.loads((out / "metrics.json").read_text())
        c = metrics["pose_calibration"]
        assert c["reason"] == reason and not c["applied"] and not c["estimated"]
        assert metrics["run"]["settings"]["run"]["calibrate_poses"] == mode
        records[mode] = [(f["status"], f["alpha"], f["beta"]) for f in read_frames_jsonl(out / "frames.jsonl")[1]]
        assert "pose calibration" not in capsys.readouterr().out  # a skipped calibration prints nothing
    assert records["auto"] == records["off"]


def test_the_flag_and_the_setting_accept_auto_and_off_only(capsys):
    assert main(["config", "--dump", "--calibrate-poses", "off"]) == 0
    assert 'calibrate_poses = "off"' in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["config", "--dump", "--calibrate-poses", "sometimes"])
    with pytest.raises(SettingsError, match="calibrate_poses must be one of auto, off"):
        RunSettings(calibrate_poses="on")


@needs_street
def test_poses_from_the_imu_are_not_calibrated():
    seq = open_sequence(STREET)
    pipeline = Pipeline(PipelineSettings.from_presets(poses="imu"), sequence=seq)
    c = calibrate_run_poses(seq, pipeline, RunSettings(), 4)
    assert not c.estimated and "'imu' pose source" in c.reason and "--poses gt" in c.reason


def test_tracked_poses_are_calibrated_and_the_run_sees_the_camera_poses():
    ts, T_w_c, T_w_b, points = scene()
    seq = _Tracked(ts, T_w_b)
    pipeline = SimpleNamespace(pose_source=GroundTruthPoses(), matcher=IdMatcher(T_w_c, points))
    c = calibrate_run_poses(seq, pipeline, RunSettings(), len(seq))
    assert c.applied and abs(c.time_offset_s - TRUE_DT) < 0.002, c.reason
    wrapped = calibrated_sequence(seq, c, len(seq))
    assert isinstance(wrapped, PoseCalibratedSequence) and len(wrapped) == len(seq)
    assert wrapped.pose_kind == "mocap" and wrapped.name == seq.name and not wrapped.has_gt_depth
    for i in range(5, 55):
        f = wrapped[i]
        assert f.index == i and f.stem == seq[i].stem
        assert rotation_error_deg(f.T_w_c, T_w_c[i]) < 0.2
        assert np.linalg.norm(f.T_w_c[:3, 3] - T_w_c[i, :3, 3]) < 0.005
    assert rotation_error_deg(seq[10].T_w_c, T_w_c[10]) > 1.0  # the sequence itself is unchanged
    assert calibrated_sequence(seq, PoseCalibration.skipped("off"), len(seq)) is seq
    assert math.isclose(c.to_json()["translation_vector_m"][0], TRUE_T_B_C[0, 3], abs_tol=0.005)


def test_the_printed_summary_has_one_line_for_an_estimate_and_none_for_a_skip():
    estimate = PoseCalibration(time_offset_s=0.015, time_offset_sigma_s=1e-4, rotation_deg=2.0, rotation_sigma_deg=0.01,
                               translation_m=0.03, translation_sigma_m=0.001, applied=True, estimated=True,
                               reason="time offset significant: time offset 15.00 +- 0.10 ms")
    lines = format_table(RunSummary(10, 10, 5, {"ok": 5}, pose_calibration=estimate.to_json())).splitlines()
    assert [ln for ln in lines if ln.startswith("pose calibration")] == [
        "pose calibration applied (time offset significant): time offset 15.0 +- 0.1 ms, rotation 2.00 +- 0.01 deg, "
        "translation 30.0 +- 1.0 mm"]
    skipped = RunSummary(10, 10, 5, {"ok": 5}, pose_calibration=PoseCalibration.skipped("exact poses").to_json())
    assert "pose calibration" not in format_table(skipped)
