"""trajectory.tum: the camera poses a run used (relative poses applied to their keyframes'
poses) and their ATE / RPE against the sequence's poses in metrics.json."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.geometry import invert_transform, make_transform
from vio_depth.evaluation import read_trajectory_tum
from vio_depth.io import open_sequence
from vio_depth.run import run_trajectory, used_poses

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"
needs_street = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled street sample missing")


def _pose(seed):
    rng = np.random.default_rng(seed)
    return make_transform(Rotation.from_rotvec(rng.normal(scale=0.2, size=3)).as_matrix(), rng.normal(size=3))


def _run(T_w_c, pairs):
    """A fake sequence (frames 0..N-1 at 10 Hz with poses ``T_w_c``, None = no pose) and fake
    results whose first pair is ``pairs[i] = (keyframe, T_kf_cur)``."""
    sequence = [SimpleNamespace(timestamp=0.1 * i, T_w_c=T) for i, T in enumerate(T_w_c)]
    results = {i: SimpleNamespace(points=SimpleNamespace(relative_pose=pairs.get(i), T_w_c=None)) for i in range(len(T_w_c))}
    return sequence, results


def test_poses_chain_from_the_origin_without_sequence_poses_and_backfill_pairs_go_backwards():
    T1, T2, T3, T5 = _pose(1), _pose(2), _pose(3), _pose(5)
    # frame 0 has no pair (the origin); 3 was backfilled with the later keyframe 5; 4 had no pose
    seq, res = _run([None] * 6, {1: (0, T1), 2: (1, T2), 3: (5, T3), 5: (1, T5)})
    traj = used_poses(seq, res)
    np.testing.assert_allclose(traj.t, [0.1, 0.2, 0.3, 0.5])
    expected = [T1, T1 @ T2, T1 @ T5 @ T3, T1 @ T5]
    np.testing.assert_allclose(traj.T_w_c, np.stack(expected), atol=1e-12)


def test_keyframes_with_a_sequence_pose_anchor_there_and_ate_measures_the_relative_poses():
    gt = [_pose(10 + i) for i in range(8)]
    truth = {i: (i - 1, invert_transform(gt[i - 1]) @ gt[i]) for i in range(1, 8)}
    seq, res = _run(gt, truth)
    report = run_trajectory(seq, res, rpe_delta_m=0.5)
    assert len(report.trajectory) == 7 and report.reference_poses == 8
    assert report.ate.rmse < 1e-12 and report.rpe.translation.rmse < 1e-12
    # relative poses 5 cm off along the camera's x, each applied to the true keyframe pose (no
    # drift): every pose is 5 cm off, and the best rigid alignment can only lower the RMSE
    off = make_transform(np.eye(3), [0.05, 0.0, 0.0])
    seq, res = _run(gt, {i: (k, T @ off) for i, (k, T) in truth.items()})
    report = run_trajectory(seq, res, rpe_delta_m=0.5)
    np.testing.assert_allclose(report.trajectory.T_w_c, np.stack([gt[i] @ off for i in range(1, 8)]), atol=1e-12)
    assert 0.005 < report.ate.rmse <= 0.05 + 1e-12 and report.note == ""
    # a sequence without poses: a trajectory, but nothing to compare it with
    seq, res = _run([None] * 8, truth)
    report = run_trajectory(seq, res, rpe_delta_m=0.5)
    assert len(report.trajectory) == 7 and report.ate is None and "no poses" in report.note


@needs_street
def test_run_writes_trajectory_tum_and_reports_ate_rpe(tmp_path, capsys):
    from vio_depth.cli import main

    out = tmp_path / "out"
    assert main(["run", str(STREET), "--out", str(out), "--max-frames", "8"]) == 0
    printed = capsys.readouterr().out
    traj = read_trajectory_tum(out / "trajectory.tum")
    seq = open_sequence(STREET)
    assert len(traj) == 8  # every frame got a pose (frame 0 from the backfill)
    np.testing.assert_allclose(traj.T_w_c, np.stack([seq[i].T_w_c for i in range(8)]), atol=1e-6)
    report = json.loads((out / "metrics.json").read_text())["trajectory"]
    assert report["poses"] == 8 and report["ate"]["ate_m"]["rmse"] < 1e-6  # --poses gt: the sequence's poses
    assert report["rpe"]["translation_m"]["n"] >= 2  # 8 frames at ~0.4 m apart, pairs 1 m apart
    assert "trajectory.tum: 8 camera poses; ATE 0.0000 m" in printed
    assert not list(out.glob("*.partial"))
