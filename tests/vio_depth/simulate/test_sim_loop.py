"""The room's closed-loop trajectory (``loop_spec``, ``generate_asl_sample(trajectory="loop")``):
periodic, inside the room and clear of its furniture, with an IMU that integrates to it, for
sequences longer than the bundled sample's few seconds. Everything here is SIMULATED."""

import numpy as np
import pytest

from vio_core.errors import InputError, UnknownNameError
from vio_core.geometry import rotation_angle_deg
from vio_depth.io import open_sequence
from vio_depth.simulate.asl import generate_asl_sample
from vio_depth.simulate.generate import ROOM_LOOP_PERIOD_S, camera_poses, loop_spec, sample_spec
from vio_depth.simulate.imu import ideal_imu, integrate_imu

SPEC = loop_spec("room")
TRAJ = SPEC.make_trajectory(SPEC.seed)
#: the room's furniture footprints (x0, y0, x1, y1) m and top heights m (vio_depth.simulate.scene_library)
FURNITURE = {"table": ((2.0, 1.9, 3.6, 2.8), 0.76), "sofa": ((0.05, 3.2, 1.1, 4.9), 0.9),
             "cabinet": ((2.2, 4.6, 4.4, 4.95), 2.0), "metal cabinet": ((5.4, 3.4, 5.95, 4.5), 1.8),
             "boxes": ((4.6, 0.3, 5.2, 0.8), 0.75), "box": ((0.6, 0.3, 1.3, 0.9), 0.55)}


def _box_distance(xy, box):
    x0, y0, x1, y1 = box
    dx = np.maximum(np.maximum(x0 - xy[:, 0], xy[:, 0] - x1), 0.0)
    dy = np.maximum(np.maximum(y0 - xy[:, 1], xy[:, 1] - y1), 0.0)
    return np.hypot(dx, dy)


def test_loop_repeats_exactly_every_period_and_turns_once_per_loop():
    t = np.linspace(0.0, ROOM_LOOP_PERIOD_S, 401)
    st = TRAJ.state(t)
    for k in (1, 7, 170):  # late loops too: no drift of any term
        later = TRAJ.state(t + k * ROOM_LOOP_PERIOD_S)
        np.testing.assert_allclose(later.p_w, st.p_w, atol=1e-9)
        np.testing.assert_allclose(later.R_w_i, st.R_w_i, atol=1e-9)
        np.testing.assert_allclose(later.v_w, st.v_w, atol=1e-9)
        np.testing.assert_allclose(later.a_w, st.a_w, atol=1e-9)
        np.testing.assert_allclose(later.omega_i, st.omega_i, atol=1e-9)
    # not trivially periodic: it moves and turns, and half a period later it is elsewhere
    half = TRAJ.state(t + ROOM_LOOP_PERIOD_S / 2)
    assert np.linalg.norm(half.p_w - st.p_w, axis=1).min() > 2.0
    heading = np.unwrap(np.arctan2(st.R_w_i[:, 1, 0], st.R_w_i[:, 0, 0]))
    assert heading[-1] - heading[0] == pytest.approx(2 * np.pi, abs=1e-9)  # faces every wall once a loop
    speed = np.linalg.norm(st.v_w, axis=1)
    assert 0.15 < speed.min() and speed.max() < 0.8  # walking pace, never at rest


def test_analytic_derivatives_match_finite_differences():
    t = np.linspace(1.0, 59.0, 40)
    h = 1e-4
    st, plus, minus = TRAJ.state(t), TRAJ.state(t + h), TRAJ.state(t - h)
    np.testing.assert_allclose(st.v_w, (plus.p_w - minus.p_w) / (2 * h), atol=1e-5)
    np.testing.assert_allclose(st.a_w, (plus.v_w - minus.v_w) / (2 * h), atol=1e-4)
    dR = (plus.R_w_i - minus.R_w_i) / (2 * h)
    S = np.einsum("kji,kjl->kil", st.R_w_i, dR)
    omega_fd = np.stack([S[:, 2, 1] - S[:, 1, 2], S[:, 0, 2] - S[:, 2, 0], S[:, 1, 0] - S[:, 0, 1]], 1) / 2
    np.testing.assert_allclose(st.omega_i, omega_fd, atol=1e-6)


def test_imu_and_camera_stay_inside_the_room_clear_of_the_furniture():
    t = np.arange(0.0, ROOM_LOOP_PERIOD_S, 0.005)  # one loop at the IMU rate is all of them
    p_i = TRAJ.state(t).p_w
    p_c = camera_poses(SPEC, TRAJ, t)[:, :3, 3]
    for p in (p_i, p_c):
        assert p[:, 0].min() > 1.0 and p[:, 0].max() < 5.0  # room: x in [0, 6], y in [0, 5], z in [0, 3]
        assert p[:, 1].min() > 1.0 and p[:, 1].max() < 4.0
        assert 1.3 < p[:, 2].min() and p[:, 2].max() < 1.5
        for name, (box, top) in FURNITURE.items():
            if top > 1.2:  # walked round at 1.4 m: only the tall pieces could be hit
                assert _box_distance(p, box).min() > 0.5, name
        assert _box_distance(p, FURNITURE["table"][0]).min() > 0.3  # never over the table (0.64 m below)


def test_every_view_sees_the_room_at_a_distance():
    pytest.importorskip("skimage")
    from vio_depth.simulate.render import render_depth
    from vio_depth.simulate.scene_library import build_scene

    scene = build_scene(SPEC.scene, SPEC.scene_seed)
    camera = SPEC.camera.scaled(0.125)
    for T_w_c in camera_poses(SPEC, TRAJ, np.linspace(0.0, ROOM_LOOP_PERIOD_S, 16, endpoint=False)):
        depth = render_depth(scene, camera, T_w_c)
        assert (depth > 0).all()  # inside the closed room: every ray hits something
        assert 0.8 < depth.min() and depth.max() < 6.0


@pytest.mark.parametrize("t0", [0.0, ROOM_LOOP_PERIOD_S - 0.5, 3590.0])
def test_noise_free_imu_integrated_over_one_second_reproduces_the_loop(t0):
    t = t0 + np.arange(201) / 200.0  # 200 Hz, 1 s, across the loop's seam and in its last minute
    gyro, accel = ideal_imu(TRAJ, t)
    st = TRAJ.state(t)
    R, p, _ = integrate_imu(t, gyro, accel, st.R_w_i[0], st.p_w[0], st.v_w[0])
    R0 = st.R_w_i[0]
    dp_true = R0.T @ (st.p_w[-1] - st.p_w[0])
    assert np.linalg.norm(R0.T @ (p[-1] - st.p_w[0]) - dp_true) < 1e-3 * np.linalg.norm(dp_true)
    assert rotation_angle_deg(st.R_w_i[-1].T @ R[-1]) < 1e-3 * max(rotation_angle_deg(R0.T @ st.R_w_i[-1]), 1.0)


def test_generated_asl_loop_is_longer_than_the_sample_with_its_imu_and_depth(tmp_path):
    pytest.importorskip("skimage")
    n = 150  # 7.5 s at 20 Hz: past the end of the room sample's own trajectory (7 s)
    with pytest.raises(InputError, match="times must lie"):
        generate_asl_sample(tmp_path / "sample", n_frames=n, scale=0.125)
    root = generate_asl_sample(tmp_path / "loop", n_frames=n, scale=0.125, trajectory="loop",
                               depth_dir=tmp_path / "depth")
    seq = open_sequence(root)
    assert len(seq) == n
    t = SPEC.frame_times(n)
    np.testing.assert_allclose(np.stack([f.T_w_c for f in seq]), camera_poses(SPEC, TRAJ, t), atol=1e-8)
    # the stored (noisy, biased) IMU, with the stored true biases removed, integrates to the loop
    imu, gt = seq.imu, seq.ground_truth
    k = slice(1000, 1201)  # 5 .. 6 s
    tt = imu.t[k] - imu.t[0]
    st = TRAJ.state(tt)
    R, p, _ = integrate_imu(tt, imu.gyro[k] - gt.gyro_bias[k], imu.accel[k] - gt.accel_bias[k], st.R_w_i[0],
                            st.p_w[0], st.v_w[0])
    dp = st.p_w[-1] - st.p_w[0]
    assert np.linalg.norm(p[-1] - st.p_w[-1]) < 0.02 * np.linalg.norm(dp)
    assert rotation_angle_deg(st.R_w_i[-1].T @ R[-1]) < 0.1
    # one exact depth map per image, named after it, at the image size
    depth = np.load(tmp_path / "depth" / f"{seq[n - 1].stem}.npy")
    assert depth.dtype == np.float32 and depth.shape == (48, 64)
    assert len(list((tmp_path / "depth").glob("*.npy"))) == n and (depth > 0.8).all()


def test_unknown_loop_and_trajectory_names_are_refused(tmp_path):
    with pytest.raises(UnknownNameError, match="room"):
        loop_spec("street")
    with pytest.raises(UnknownNameError, match="loop"):
        generate_asl_sample(tmp_path / "x", n_frames=2, scale=0.125, trajectory="circle")
    assert loop_spec("room").camera == sample_spec("room").camera  # the sample's camera, mounting, noise
    assert np.array_equal(loop_spec("room").T_i_c, sample_spec("room").T_i_c)
