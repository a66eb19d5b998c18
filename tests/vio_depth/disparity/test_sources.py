"""Disparity sources and the registry: files, the sequence's own, SIMULATED, model; clear errors."""

from pathlib import Path

import numpy as np
import pytest

from vio_core import Camera, InputError, SequenceFormatError, SettingsError, UnknownNameError
from vio_depth.disparity import (
    DisparityKind,
    DisparitySettings,
    DisparitySpec,
    FileDisparity,
    SimulatedDisparitySource,
    check_disparity,
    create_disparity_source,
    disparity_preset,
    simulate_disparity,
)
from vio_depth.frame import Frame

CAM = Camera(16, 12, 20.0, 20.0, 7.5, 5.5)
STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"


def _frame(index=0, gt=None, stem=None):
    return Frame(index, float(index), stem or f"{index:06d}", CAM, np.eye(4),
                 load_image=lambda: np.zeros((12, 16, 3), np.uint8),
                 load_gt_depth=None if gt is None else (lambda: gt))


class _FakeSequence:
    def __init__(self, root, disparity=None, has_gt_depth=True):
        self.root, self.disparity, self.has_gt_depth = Path(root), disparity, has_gt_depth


def test_file_source_reads_checks_and_reports_missing_frames(tmp_path):
    d = np.random.default_rng(0).uniform(0, 5, (12, 16)).astype(np.float32)
    np.save(tmp_path / "000000.npy", d)
    np.save(tmp_path / "000001.npy", np.zeros((3, 3), np.float32))
    src = FileDisparity(tmp_path)
    assert src.kind == DisparityKind.FILES
    assert np.array_equal(src(_frame(0)), d)
    with pytest.raises(InputError, match="000001.npy.*must be \\(12, 16\\)"):
        src(_frame(1))
    assert src(_frame(2)) is None  # missing: the frame gets status no_disparity
    with pytest.raises(SequenceFormatError, match="000002.npy"):
        FileDisparity(tmp_path, required=True)(_frame(2))  # a sequence that declared it
    with pytest.raises(InputError, match="does not exist"):
        FileDisparity(tmp_path / "nope")


def test_check_disparity_keeps_nan_and_refuses_inf_and_ints():
    d = np.ones((12, 16), np.float64)
    d[0, 0] = np.nan
    out = check_disparity(d, _frame(), "x")
    assert out.dtype == np.float32 and np.isnan(out[0, 0])
    d[1, 1] = np.inf
    with pytest.raises(InputError, match="infinite"):
        check_disparity(d, _frame(), "x")
    with pytest.raises(InputError, match="float"):
        check_disparity(np.ones((12, 16), np.int32), _frame(), "x")


def test_registry_builds_each_kind_from_settings(tmp_path):
    gt = np.full((12, 16), 4.0, np.float32)
    gt[:, 8:] = 8.0
    spec = DisparitySpec.simulated(7)
    seq = _FakeSequence(tmp_path, spec)
    own = create_disparity_source(DisparitySettings(), seq)
    assert own.kind == DisparityKind.SIMULATED and own.densify is None
    assert np.array_equal(own(_frame(3, gt)), simulate_disparity(gt, 7, 3, disparity_preset("default")).disparity)
    sim = create_disparity_source(DisparitySettings(source="simulated", seed=2), seq)
    assert isinstance(sim, SimulatedDisparitySource) and sim.densify is not None and sim.seed == 2
    (tmp_path / "d").mkdir()
    files = create_disparity_source(DisparitySettings(source="FILES", path=str(tmp_path / "d")), seq)
    assert isinstance(files, FileDisparity) and not files.required
    on_disk = create_disparity_source(DisparitySettings(), _FakeSequence(tmp_path, DisparitySpec.files("d")))
    assert isinstance(on_disk, FileDisparity) and on_disk.required


def test_registry_errors_are_clear(tmp_path):
    with pytest.raises(InputError, match="carries no disparity maps.*--disparity simulated"):
        create_disparity_source(DisparitySettings(), _FakeSequence(tmp_path))
    with pytest.raises(InputError, match="needs ground-truth depth"):
        create_disparity_source(DisparitySettings(source="simulated"), _FakeSequence(tmp_path, has_gt_depth=False))
    with pytest.raises(UnknownNameError, match="files, model, sequence, simulated"):
        DisparitySettings(source="guess")
    with pytest.raises(SettingsError, match="--disparity-dir"):
        DisparitySettings(source="files")
    with pytest.raises(SettingsError, match="no path"):
        DisparitySettings(source="simulated", path="x")
    with pytest.raises(SettingsError, match="seed"):
        DisparitySettings(seed=-1)
    with pytest.raises(UnknownNameError, match="clean, default, hard"):
        DisparitySettings(simulation="soft")


def test_model_source_without_weights_fails_before_running(tmp_path):
    with pytest.raises(InputError):
        create_disparity_source(DisparitySettings(source="model", path=str(tmp_path / "missing.pth")))
