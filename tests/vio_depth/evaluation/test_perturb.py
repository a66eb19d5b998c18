"""Tests of vio_depth/evaluation/perturb.py: each perturbation against its known statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import SettingsError, ShapeError
from vio_core.geometry import invert_transform, make_transform
from vio_depth.evaluation import (
    STUDIES,
    ImuNoiseBoost,
    PerturbedSequence,
    PoseNoise,
    add_outliers,
    depth_noise,
    lidar_points,
    perturb_imu,
    perturb_pose,
    shift_pixels,
)
from vio_depth.evaluation.reference_points import beam_rows
from vio_depth.frame import ImuData

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"


def test_depth_noise_has_the_requested_relative_sigma_and_is_seeded():
    z = np.full(20000, 10.0)
    noisy = depth_noise(z, 0.05, seed=[1, 2])
    rel = noisy / z - 1.0
    assert abs(rel.std() - 0.05) < 0.002 and abs(rel.mean()) < 0.002  # 20k draws: sigma/sqrt(2N) ~ 2.5e-4
    assert np.array_equal(noisy, depth_noise(z, 0.05, seed=[1, 2]))
    assert not np.array_equal(noisy, depth_noise(z, 0.05, seed=[1, 3]))
    np.testing.assert_array_equal(depth_noise(z, 0.0, seed=0), z)
    assert np.array_equal(z, np.full(20000, 10.0))  # input untouched


def test_depth_noise_never_returns_non_positive_depths():
    noisy = depth_noise(np.ones(5000), 1.0, seed=0)  # about 16 % of draws go below zero
    bad = np.isnan(noisy)
    assert 0.1 < bad.mean() < 0.22 and (noisy[~bad] > 0).all()
    with pytest.raises(SettingsError):
        depth_noise(np.ones(3), -0.1, seed=0)
    with pytest.raises(ShapeError):
        depth_noise(np.ones((3, 2)), 0.1, seed=0)


def test_shift_pixels_moves_points_by_the_given_length():
    uv = np.random.default_rng(0).uniform(0, 100, (500, 2))
    same = shift_pixels(uv, 4.0, seed=7)
    d = same - uv
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 4.0)
    np.testing.assert_allclose(d, np.broadcast_to(d[0], d.shape))  # one direction for all
    each = shift_pixels(uv, 4.0, seed=7, per_point=True) - uv
    np.testing.assert_allclose(np.linalg.norm(each, axis=1), 4.0)
    assert np.std(np.arctan2(each[:, 1], each[:, 0])) > 1.0  # directions spread over the circle
    np.testing.assert_array_equal(shift_pixels(uv, 0.0, seed=7), uv)


def test_lidar_points_are_the_reference_point_rows():
    gt = np.zeros((60, 40), np.float32)
    gt[10:50] = np.arange(40, dtype=np.float32) + 1.0
    pts = lidar_points(gt, 4)
    rows = beam_rows(gt, 4)
    assert sorted(set(pts.uv[:, 1].astype(int))) == rows.tolist()
    assert len(pts.depth) == 4 * 40
    np.testing.assert_array_equal(pts.depth, gt[pts.uv[:, 1].astype(int), pts.uv[:, 0].astype(int)])


def test_add_outliers_replaces_the_exact_fraction_by_wrong_depths():
    z = np.random.default_rng(0).uniform(2.0, 60.0, 1000)
    draw = add_outliers(z, 0.3, seed=4, min_depth=1.0, max_depth=80.0)
    assert draw.is_outlier.sum() == 300
    np.testing.assert_array_equal(draw.depth[~draw.is_outlier], z[~draw.is_outlier])
    ratio = np.maximum(draw.depth / z, z / draw.depth)[draw.is_outlier]
    assert (ratio >= 1.25).all()
    assert (draw.depth >= 1.0).all() and (draw.depth <= 80.0).all()
    again = add_outliers(z, 0.3, seed=4, min_depth=1.0, max_depth=80.0)
    assert np.array_equal(again.depth, draw.depth)
    assert add_outliers(z, 0.0, seed=4, min_depth=1.0, max_depth=80.0).is_outlier.sum() == 0
    with pytest.raises(SettingsError):
        add_outliers(z, 1.5, seed=0, min_depth=1.0, max_depth=80.0)
    with pytest.raises(SettingsError):
        add_outliers(z, 0.1, seed=0, min_depth=1.0, max_depth=1.2)


def _imu(n=40000, rate=200.0, **densities):
    t = np.arange(n) / rate
    return ImuData(t, np.tile([0.01, 0.0, 0.0], (n, 1)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4), **densities)


def test_perturb_imu_adds_noise_matching_the_scaled_densities():
    imu = _imu(gyro_noise=1e-3, accel_noise=2e-2, gyro_bias_walk=0.0, accel_bias_walk=0.0)
    out = perturb_imu(imu, 3.0, seed=0, gyro_bias=(0.0, 0.002, 0.0), accel_bias=(0.1, 0.0, 0.0))
    assert out.gyro_noise == pytest.approx(3e-3) and out.accel_noise == pytest.approx(6e-2)
    added_g, added_a = out.gyro - imu.gyro, out.accel - imu.accel
    k = np.sqrt(3.0**2 - 1.0) * np.sqrt(200.0)  # sqrt(s^2 - 1) / sqrt(dt)
    np.testing.assert_allclose(added_g.std(axis=0), 1e-3 * k, rtol=0.02)
    np.testing.assert_allclose(added_a.std(axis=0), 2e-2 * k, rtol=0.02)
    np.testing.assert_allclose(added_g.mean(axis=0), [0.0, 0.002, 0.0], atol=4 * 1e-3 * k / 200)
    np.testing.assert_allclose(added_a.mean(axis=0), [0.1, 0.0, 0.0], atol=4 * 2e-2 * k / 200)
    np.testing.assert_array_equal(out.t, imu.t)
    assert np.array_equal(out.gyro, perturb_imu(imu, 3.0, seed=0, gyro_bias=(0.0, 0.002, 0.0)).gyro)


def test_perturb_imu_bias_walk_increments_and_identity_at_scale_one():
    imu = _imu(gyro_noise=0.0, accel_noise=0.0, gyro_bias_walk=1e-3, accel_bias_walk=0.0)
    out = perturb_imu(imu, 2.0, seed=1)
    inc = np.diff(out.gyro - imu.gyro, axis=0)
    np.testing.assert_allclose(inc.std(axis=0), 1e-3 * np.sqrt(3.0) * np.sqrt(1 / 200.0), rtol=0.02)
    assert out.gyro_bias_walk == pytest.approx(2e-3)
    np.testing.assert_array_equal(out.accel, imu.accel)  # zero densities: nothing added
    same = perturb_imu(_imu(), 1.0, seed=0)
    np.testing.assert_array_equal(same.gyro, _imu().gyro)
    with pytest.raises(SettingsError, match="cannot be removed"):
        perturb_imu(imu, 0.5, seed=0)


def test_perturb_pose_has_the_requested_sigmas_in_the_camera_frame():
    rng = np.random.default_rng(0)
    T = np.stack([make_transform(Rotation.random(random_state=i).as_matrix(), rng.normal(0, 10, 3))
                  for i in range(4000)])
    out = perturb_pose(T, 0.5, 0.02, seed=[3, 1])
    delta = np.einsum("nij,njk->nik", np.linalg.inv(T), out)
    rotvec = Rotation.from_matrix(delta[:, :3, :3]).as_rotvec()
    np.testing.assert_allclose(rotvec.std(axis=0), np.radians(0.5), rtol=0.05)
    np.testing.assert_allclose(delta[:, :3, 3].std(axis=0), 0.02, rtol=0.05)
    one = perturb_pose(T[5], 0.5, 0.02, seed=9)
    assert one.shape == (4, 4)
    np.testing.assert_allclose(one[:3, :3] @ one[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(perturb_pose(T[:3], 0.0, 0.0, seed=0), T[:3])


@pytest.fixture(scope="module")
def street():
    from vio_depth.io import open_sequence

    return open_sequence(STREET)


def test_perturbed_sequence_is_per_frame_seeded_and_leaves_pixels_alone(street):
    seq = PerturbedSequence(street, seed=5, pose_noise=PoseNoise(1.0, 0.1), imu_noise=ImuNoiseBoost(2.0))
    assert len(seq) == len(street) and seq.has_gt_depth and seq.disparity == street.disparity
    a = seq.frame(7).T_w_c
    seq.frame(3)  # reading another frame first changes nothing
    np.testing.assert_array_equal(PerturbedSequence(street, seed=5, pose_noise=PoseNoise(1.0, 0.1)).frame(7).T_w_c, a)
    d = invert_transform(street.frame(7).T_w_c) @ a
    assert 0 < np.linalg.norm(d[:3, 3]) < 1.0
    assert seq.imu.gyro_noise == pytest.approx(2 * street.imu.gyro_noise)
    np.testing.assert_array_equal(seq.frame(7).gt_depth(), street.frame(7).gt_depth())
    plain = PerturbedSequence(street, seed=5)
    np.testing.assert_array_equal(plain.frame(7).T_w_c, street.frame(7).T_w_c)
    assert plain.imu is street.imu


def test_studies_name_functions_of_the_module_and_start_unperturbed():
    import vio_depth.evaluation.perturb as perturb

    for study in STUDIES.values():
        assert callable(getattr(perturb, study.function))
        assert len(study.x()) == len(study.values) >= 5
    assert STUDIES["depth_noise"].x()[0] == 0.0 and STUDIES["outliers"].x()[0] == 0.0
    assert STUDIES["imu_noise"].x()[0] == 1.0 and STUDIES["lidar_beams"].x()[-1] == 64
