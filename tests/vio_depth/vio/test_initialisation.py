"""The dynamic initialisation's parts on synthetic scenes of known truth: up-to-scale SfM,
the visual-inertial alignment (scale, gravity, velocities, gyroscope bias) and its refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.geometry import invert_transform, make_transform
from vio_depth.landmarks import FrameMatches
from vio_depth.pipeline import POSE_PRESETS
from vio_depth.poses import preintegration_params
from vio_depth.vio import SfmKeyframe, VioInitSettings, align, reconstruct

from .synthetic import IdMatcher, make_scene

pytest.importorskip("gtsam")

KEYS = list(range(0, 40, 5))  # 8 keyframes over 1.75 s


@pytest.fixture(scope="module")
def scene():
    return make_scene(duration_s=2.5, seed=11)


def _keyframes(scene, keys=KEYS, keep=None):
    m = IdMatcher()
    feats = [scene.features[k] if keep is None else keep(scene.features[k]) for k in keys]
    out = []
    for j, k in enumerate(keys):
        matches = tuple(FrameMatches.from_matches(keys[i], m.match(feats[j], feats[i])) for i in range(max(0, j - 3), j))
        out.append(SfmKeyframe(k, scene.camera, np.asarray(feats[j].keypoints, float), matches))
    return out


def _sim3_error(T_est, T_true):
    """Rotation errors (deg) of the relative rotations to the first frame, and the position
    error after the best scale (fraction of the span)."""
    R0e, R0t = T_est[0, :3, :3], T_true[0, :3, :3]
    rot = [np.degrees(Rotation.from_matrix((R0t.T @ Tt[:3, :3]).T @ (R0e.T @ Te[:3, :3])).magnitude())
           for Te, Tt in zip(T_est, T_true)]
    p_e = np.stack([(invert_transform(T_est[0]) @ T)[:3, 3] for T in T_est])
    p_t = np.stack([(invert_transform(T_true[0]) @ T)[:3, 3] for T in T_true])
    s = np.sum(p_e * p_t) / np.sum(p_e * p_e)
    return max(rot), float(np.max(np.linalg.norm(s * p_e - p_t, axis=1)) / np.max(np.linalg.norm(p_t, axis=1)))


def test_sfm_reconstructs_the_keyframes_up_to_scale(scene):
    res = reconstruct(_keyframes(scene))
    assert res.ok, res.reason
    rot, pos = _sim3_error(res.T_c0_c, scene.T_w_c[KEYS])
    assert rot < 0.25 and pos < 0.02, (rot, pos)  # 0.5 px keypoint noise
    assert res.landmarks >= 100 and res.median_residual_px < 1.0
    np.testing.assert_allclose(res.T_c0_c[0], np.eye(4), atol=1e-6)


def test_sfm_refuses_too_few_tracks(scene):
    res = reconstruct(_keyframes(scene, keep=lambda f: type(f)(f.keypoints[:12], f.descriptors[:12], f.scores[:12],
                                                                 f.image_size)))
    assert not res.ok and "too few tracks" in res.reason


def _aligned(scene, imu=None, T=None, times=None, settings=VioInitSettings()):
    imu = scene.imu if imu is None else imu
    params = preintegration_params(imu, POSE_PRESETS["vio_offline"].imu)
    s_true = 3.7  # reconstruction units per ... : positions divided by it
    T_true = scene.T_w_c[KEYS] if T is None else T
    T_c0 = np.stack([invert_transform(T_true[0]) @ Tk for Tk in T_true])
    T_c0[:, :3, 3] /= s_true
    t = np.array([scene.frames[k].timestamp for k in KEYS]) if times is None else times
    return s_true, align(T_c0, t, imu, params, settings, 0.25)


def test_alignment_recovers_scale_gravity_velocities_and_gyro_bias(scene):
    s_true, al = _aligned(scene)
    assert al.ok, al.reason
    assert al.scale == pytest.approx(s_true, rel=0.01)
    assert al.scale_sigma < 0.02 and abs(al.gravity_error) < 0.2
    np.testing.assert_allclose(al.gyro_bias, scene.gyro_bias, atol=3e-4)
    # gravity: the aligned world's z is up; compare the tilt of every camera with the truth
    for T_est, T_true in zip(al.T_w_c, scene.T_w_c[KEYS]):
        up_e, up_t = T_est[:3, :3].T @ [0, 0, 1], T_true[:3, :3].T @ [0, 0, 1]
        assert np.degrees(np.arccos(np.clip(up_e @ up_t, -1, 1))) < 0.5
    speeds = np.linalg.norm(al.velocity_w, axis=1)
    np.testing.assert_allclose(speeds, np.linalg.norm(scene.v_w[KEYS], axis=1), rtol=0.03)


def test_alignment_refuses_with_a_reason(scene):
    # uniform motion: the accelerometer reads gravity only (no acceleration) -> too little excitation
    R_w_i = scene.imu_truth_R_w_i
    flat = replace(scene.imu, accel=np.einsum("kji,j->ki", R_w_i, [0.0, 0.0, 9.81]))
    _, al = _aligned(scene, imu=flat)
    assert not al.ok and "excitation" in al.reason
    # an accelerometer reading 30 % too high: gravity cannot be 9.81 m/s^2
    strong = replace(scene.imu, accel=scene.imu.accel * 1.3)
    _, al = _aligned(scene, imu=strong)
    assert not al.ok and "gravity" in al.reason
    # images that turn the other way than the gyroscope: an implausible gyroscope bias
    T = scene.T_w_c[KEYS].copy()
    for k in range(len(T)):
        T[k] = T[0] @ make_transform((T[0, :3, :3].T @ T[k, :3, :3]).T, (invert_transform(T[0]) @ T[k])[:3, 3])
    _, al = _aligned(scene, T=T)
    assert not al.ok and "gyroscope bias" in al.reason
