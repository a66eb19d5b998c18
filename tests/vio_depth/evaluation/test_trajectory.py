"""Trajectory files, ATE and RPE (evo's definitions) on hand-computed cases."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import make_transform
from vio_depth.evaluation import (
    CameraTrajectory,
    absolute_trajectory_error,
    associate,
    pairs_by_path,
    read_trajectory_tum,
    relative_pose_error,
    umeyama_alignment,
    write_trajectory_tum,
)


def _traj(positions, yaw_deg=None, t=None):
    p = np.asarray(positions, float)
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, 3] = p
    if yaw_deg is not None:
        T[:, :3, :3] = Rotation.from_euler("z", np.asarray(yaw_deg, float)[:, None], degrees=True).as_matrix()
    return CameraTrajectory(np.arange(len(p), dtype=float) if t is None else np.asarray(t, float), T)


LINE = [[x, 0.0, 0.0] for x in range(6)]  # 1 m steps along x
CROSS = [[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]]


# --------------------------------------------------------------------------- ATE
def test_ate_is_zero_for_a_rigidly_moved_estimate_and_recovers_the_transform():
    rng = np.random.default_rng(0)
    ref = _traj(rng.normal(size=(20, 3)), yaw_deg=rng.uniform(-90, 90, 20))
    T = make_transform(Rotation.from_euler("zyx", [30, -10, 5], degrees=True).as_matrix(), [1.0, -2.0, 0.5])
    est = CameraTrajectory(ref.t, T @ ref.T_w_c)  # the estimate lives in another world frame
    ate = absolute_trajectory_error(est, ref)
    assert ate.rmse < 1e-12 and ate.scale == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(ate.T_ref_est @ T, np.eye(4), atol=1e-12)


def test_ate_does_not_correct_scale_and_reports_it_separately():
    """A cross of 4 points at 1 m, estimated 10 % too large: by symmetry the SE(3) alignment is
    the identity and each point is 0.1 m off, so ATE = 0.1 m; the Sim(3) scale is 1.1."""
    ref = _traj(CROSS)
    est = _traj(1.1 * np.asarray(CROSS))
    ate = absolute_trajectory_error(est, ref)
    assert ate.rmse == pytest.approx(0.1, abs=1e-12)
    np.testing.assert_allclose(ate.errors, 0.1, atol=1e-12)
    assert ate.scale == pytest.approx(1 / 1.1, abs=1e-12)  # maps the estimate onto the reference
    assert ate.path_length == pytest.approx(3 * np.sqrt(2))


def test_ate_with_one_displaced_pose_hand_computed():
    """Reference on a line, one pose of the estimate displaced 0.4 m along z (out of the
    line): the best rigid fit tilts/shifts by the least-squares amount; check against the
    closed form for 4 collinear points plus the translation-only optimum as an upper bound."""
    ref = _traj([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    est_p = np.array(ref.positions)
    est_p[3, 2] = 0.4
    ate = absolute_trajectory_error(_traj(est_p), ref)
    # translation only: shift z by -0.1 -> errors 0.1, 0.1, 0.1, 0.3 -> RMSE sqrt(0.12 / 4)
    assert ate.rmse < np.sqrt(0.12 / 4)
    # with the tilt: z residuals of the line fit z ~ a + b x to (0, 0, 0, 0.4) over x = 0..3
    x = np.arange(4.0)
    z = np.array([0, 0, 0, 0.4])
    A = np.stack([np.ones(4), x], 1)
    resid = z - A @ np.linalg.lstsq(A, z, rcond=None)[0]
    assert ate.rmse == pytest.approx(np.sqrt(np.mean(resid**2)), rel=0.02)  # small-angle: rotation ~ shear


def test_umeyama_with_scale_recovers_a_similarity():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(30, 3))
    R = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    y = 2.5 * x @ R.T + [1.0, 2.0, 3.0]
    R_hat, t_hat, c = umeyama_alignment(x, y, with_scale=True)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, [1.0, 2.0, 3.0], atol=1e-12)
    assert c == pytest.approx(2.5)
    with pytest.raises(InputError, match="at least 3"):
        umeyama_alignment(x[:2], y[:2])


def test_association_follows_evo():
    t_ref = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    t_est = np.array([0.004, 0.196, 0.35, 0.41])  # 0.35 is 0.05 s from either neighbour
    i_est, i_ref = associate(t_est, t_ref, max_diff=0.01)
    assert i_est.tolist() == [0, 1, 3] and i_ref.tolist() == [0, 2, 4]
    i_est, i_ref = associate(t_ref, t_est, max_diff=0.01)  # the longer one may be either
    assert i_est.tolist() == [0, 2, 4] and i_ref.tolist() == [0, 1, 3]


# --------------------------------------------------------------------------- RPE
def test_pairs_by_path_reproduce_evo_consecutive_rule():
    # evo 1.38: index 0, then each index where the path since the last mark reaches delta
    assert pairs_by_path(np.asarray(LINE), 1.0) == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]
    assert pairs_by_path(np.asarray(LINE), 2.0) == [(0, 2), (2, 4)]
    assert pairs_by_path(np.asarray(LINE), 2.5) == [(0, 3)]  # path 3 >= 2.5 at index 3, then 2 < 2.5
    assert pairs_by_path(np.asarray(LINE), 2.0, tol=0.2, all_pairs=True) == [(0, 2), (1, 3), (2, 4), (3, 5)]


def test_rpe_translation_hand_computed():
    """One step of the estimate is 1.2 m instead of 1 m: over delta = 1 m the pairs are
    consecutive poses and only (2,3) errs, by 0.2 m: RMSE sqrt(0.04 / 5)."""
    ref = _traj(LINE)
    est_p = np.asarray(LINE)
    est_p[3:, 0] += 0.2
    rpe = relative_pose_error(_traj(est_p), ref, 1.0)
    assert rpe.pairs.tolist() == [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]]
    np.testing.assert_allclose(rpe.translation_errors, [0, 0, 0.2, 0, 0], atol=1e-12)
    assert rpe.translation.rmse == pytest.approx(np.sqrt(0.04 / 5))
    assert rpe.translation.mean == pytest.approx(0.04) and rpe.translation.median == pytest.approx(0.0)
    assert rpe.translation.max == pytest.approx(0.2)
    np.testing.assert_allclose(rpe.rotation_errors_deg, 0.0, atol=1e-9)
    two = relative_pose_error(_traj(est_p), ref, 2.0)  # estimate's path 1, 2 -> mark 2; 1.2, 2.2 -> mark 4
    assert two.pairs.tolist() == [[0, 2], [2, 4]]
    np.testing.assert_allclose(two.translation_errors, [0.0, 0.2], atol=1e-12)
    # pairs from the reference instead: the same marks here (1 m steps), same errors
    assert relative_pose_error(_traj(est_p), ref, 2.0, pairs_from="reference").pairs.tolist() == [[0, 2], [2, 4]]


def test_rpe_rotation_hand_computed():
    """The estimate turns by 10 deg between poses 2 and 3 (the reference does not): the pair
    (2,3) errs by 10 deg with no translation error; (3,4) and (4,5) by 0 deg, but their 1 m
    steps, seen from the turned camera, point 10 deg off: 2 sin(5 deg) m each."""
    ref = _traj(LINE)
    est = _traj(LINE, yaw_deg=[0, 0, 0, 10, 10, 10])
    rpe = relative_pose_error(est, ref, 1.0)
    np.testing.assert_allclose(rpe.rotation_errors_deg, [0, 0, 10, 0, 0], atol=1e-9)
    s = 2 * np.sin(np.radians(5))
    np.testing.assert_allclose(rpe.translation_errors, [0, 0, 0, s, s], atol=1e-12)


def test_rpe_is_invariant_to_a_rigid_transform_of_the_estimate():
    rng = np.random.default_rng(2)
    ref = _traj(np.cumsum(rng.normal(size=(40, 3)), 0), yaw_deg=np.cumsum(rng.normal(size=40) * 5))
    noisy = ref.T_w_c.copy()
    noisy[:, :3, 3] += rng.normal(scale=0.05, size=(40, 3))
    T = make_transform(Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix(), [5.0, 0.0, -1.0])
    a = relative_pose_error(CameraTrajectory(ref.t, noisy), ref, 3.0)
    b = relative_pose_error(CameraTrajectory(ref.t, T @ noisy), ref, 3.0)
    assert len(a.pairs) > 3
    np.testing.assert_allclose(a.translation_errors, b.translation_errors, atol=1e-9)


# --------------------------------------------------------------------------- files
def test_tum_round_trip_only_posed_frames(tmp_path):
    rng = np.random.default_rng(3)
    poses = [make_transform(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3)) for _ in range(5)]
    poses[1] = None  # a frame without a pose gets no line
    t = 1403715273.262142976 + 0.05 * np.arange(5)
    traj = CameraTrajectory.from_optional_poses(t, poses)
    path = write_trajectory_tum(tmp_path / "trajectory.tum", traj)
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == 4 and len(lines[0].split()) == 8
    back = read_trajectory_tum(path)
    np.testing.assert_allclose(back.t, t[[0, 2, 3, 4]], atol=1e-6)
    np.testing.assert_allclose(back.T_w_c, np.stack([p for p in poses if p is not None]), atol=1e-8)
    assert not list(tmp_path.glob("*.partial"))  # written atomically


def test_reading_a_bad_tum_file_names_file_and_line(tmp_path):
    path = tmp_path / "bad.tum"
    path.write_text("# header\n0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 1\n")
    with pytest.raises(SequenceFormatError, match=r"bad\.tum:3: expected 8 columns"):
        read_trajectory_tum(path)


# --------------------------------------------------------------------------- against evo itself
def test_matches_evo_when_installed():
    """Only where evo is installed (it is not a dependency): same ATE and RPE figures."""
    evo_sync = pytest.importorskip("evo.core.sync")
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(4)
    n = 60
    ref = _traj(np.cumsum(rng.normal(size=(n, 3)), 0), yaw_deg=np.cumsum(rng.normal(size=n) * 3))
    est_T = ref.T_w_c.copy()
    est_T[:, :3, 3] = 1.02 * est_T[:, :3, 3] + rng.normal(scale=0.05, size=(n, 3))
    est = CameraTrajectory(ref.t + 0.003, est_T)
    e_ref = PoseTrajectory3D(poses_se3=list(ref.T_w_c), timestamps=ref.t)
    e_est = PoseTrajectory3D(poses_se3=list(est.T_w_c), timestamps=est.t)
    e_ref, e_est = evo_sync.associate_trajectories(e_ref, e_est, max_diff=0.01)
    e_est.align(e_ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((e_ref, e_est))
    assert absolute_trajectory_error(est, ref).rmse == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse))
    for relation, ours_stat in ((metrics.PoseRelation.translation_part, "translation"),
                                (metrics.PoseRelation.rotation_angle_deg, "rotation_deg")):
        for all_pairs in (False, True):
            rpe = metrics.RPE(relation, 5.0, metrics.Unit.meters, all_pairs=all_pairs)
            rpe.process_data((e_ref, e_est))
            ours = getattr(relative_pose_error(est, ref, 5.0, all_pairs=all_pairs), ours_stat)
            assert ours.rmse == pytest.approx(rpe.get_statistic(metrics.StatisticsType.rmse))
            assert ours.n == len(rpe.error)
