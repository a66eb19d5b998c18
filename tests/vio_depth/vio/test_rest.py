"""Rest detection of the odometry (vio_depth/vio/rest.py) on SIMULATED scenes of known truth:
a creeping camera is never held more than 1 cm from the truth, a true rest is still detected,
the covariance of a resting frame grows with time, and the IMU's zero-velocity chi-square."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_distribution

from vio_core.errors import SettingsError
from vio_core.geometry import invert_transform
from vio_depth.frame import ImuData
from vio_depth.pipeline import POSE_PRESETS
from vio_depth.vio import RestSettings
from vio_depth.vio import VioEstimator, VioStatus, zero_velocity_chi2

from .synthetic import IdMatcher, creeping, make_scene

pytest.importorskip("gtsam")

SETTINGS = POSE_PRESETS["vio_offline"]
STILL_S = 2.0  # the creeping scenes rest until then (static start at 1 s), then creep


def _run(scene):
    est = VioEstimator(scene.imu, IdMatcher(), SETTINGS)
    return [est.process(f.index, f.timestamp, f.camera, scene.features[k]) for k, f in enumerate(scene.frames)]


def _errors(scene, out):
    """{frame: metres} of every posed frame of the first session: its position relative to the
    start frame, in the start camera, against the truth (the world's yaw is arbitrary)."""
    start = next(i for i, v in enumerate(out) if v.initialised)
    end = next((i for i, v in enumerate(out) if i > start and v.status == VioStatus.LOST), len(out))
    Ts_e, Ts_t = invert_transform(out[start].T_w_c), invert_transform(scene.T_w_c[start])
    return {i: float(np.linalg.norm((Ts_e @ out[i].T_w_c)[:3, 3] - (Ts_t @ scene.T_w_c[i])[:3, 3]))
            for i in range(start, end) if out[i].ok}


SIDEWAYS = (-0.62, 0.77, 0.0)  # across the creeping scene's view (the camera looks along (0.77, 0.62, -0.13))


@pytest.mark.parametrize("speed", [0.01, 0.03, 0.10])
def test_a_creeping_camera_is_never_held_more_than_1cm_from_the_truth(speed):
    """Still until 2 s, then a straight creep at ``speed`` m/s (mostly along the view: the
    hardest direction for the images). Every posed frame stays within 1 cm of the truth and
    the rest ends once the camera creeps.

    The rule before (IMU still for 1 s, keypoints within 1 px of the previous frame and 3 px of
    the newest keyframe; measured on this scene, seed 11, with the code of main at b331fd9)
    held the camera at the start's position for 69 / 59 / 22 frames after the creep began,
    3.2 / 8.1 / 8.5 cm from the truth at 1 / 3 / 10 cm/s, with a constant 5 mm sigma. With a
    fixed 0.2 % of the depth since the rest began: 0.70 / 0.75 / 0.69 cm. Measured now (0.1 %
    plus 1 sigma of the gyroscope's rotation uncertainty): 0.40 / 0.32 / 0.19 cm."""
    _assert_creep_caught(speed, (0.6, 0.8, 0.0))


@pytest.mark.parametrize("speed", [0.01, 0.03, 0.10])
def test_a_camera_creeping_sideways_is_never_held_more_than_1cm_from_the_truth(speed):
    """The same scene creeping across the view: the hard direction for a rotation-aware test,
    since a sideways motion moves the keypoints almost as a rotation does (a gyroscope bias
    error). The test counts it beyond the gyroscope's rotation uncertainty only, which the
    simulated gyroscope (datasheet noise) keeps small. Measured (seed 11): at most 0.50 / 0.45
    / 0.83 cm from the truth (the last on a tracked frame after the rest); with rotation fully
    free (fitted from the images) it was 1.95 / 2.70 / 3.00 cm. Other seeds (1-4) reach
    0.65-1.44 cm at 1 cm/s: a static start's gyroscope bias off by 3 sigma turns the creep into
    a rotation; the fixed 0.2 % rule of before reached 1.00-1.74 cm there."""
    _assert_creep_caught(speed, SIDEWAYS)


def test_a_camera_tracked_in_uniform_motion_does_not_rest():
    """Creeping sideways at 10 cm/s (seed 1): once the odometry tracks the creep again, its
    keyframes' velocity says the camera moves, and no frame rests (OpenVINS's
    ``zupt_max_velocity``). Without that check every other frame rested there, held 5 mm
    behind: uniform motion passes the IMU test, 5 mm at 3-6 m moves keypoints less than the
    1.5 px frame-to-frame limit, and the motion since the previous frame (the anchor) stays
    within 0.1 % of the depth."""
    scene = make_scene(duration_s=5.0, seed=1, trajectory=creeping(0.10, still_s=STILL_S, direction_w=SIDEWAYS))
    out = _run(scene)
    tracked = [i for i, v in enumerate(out) if v.status == VioStatus.TRACKING and scene.frames[i].timestamp > STILL_S]
    assert tracked, [v.status.value for v in out]
    later = [i for i in range(tracked[0], len(out)) if out[i].status == VioStatus.STILL]
    assert not later, [(i, out[i].reason) for i in later[:3]]


def _assert_creep_caught(speed, direction_w):
    scene = make_scene(duration_s=5.0, seed=11, trajectory=creeping(speed, still_s=STILL_S, direction_w=direction_w))
    out = _run(scene)
    err = _errors(scene, out)
    worst = max(err, key=err.get)
    assert err[worst] < 0.01, (worst, err[worst], out[worst].status, out[worst].reason)
    creeping_frames = [i for i, f in enumerate(scene.frames) if f.timestamp > STILL_S + 0.5]
    assert any(out[i].status != VioStatus.STILL for i in creeping_frames)


def test_a_true_rest_is_detected_and_its_covariance_grows():
    """The same scene's still second (1 s to 2 s after the static start): every frame rests, at
    the start's position (the true camera too), and its position sigma grows with the time at
    rest (a random walk: ``translation_random_walk * sqrt(dt)``), never frozen."""
    scene = make_scene(duration_s=5.0, seed=11, trajectory=creeping(0.03, still_s=STILL_S))
    out = _run(scene)
    start = next(i for i, v in enumerate(out) if v.initialised)
    resting = [i for i, f in enumerate(scene.frames) if start < i and f.timestamp < STILL_S - 0.05]
    assert len(resting) >= 15
    assert all(out[i].status == VioStatus.STILL for i in resting), {out[i].status.value for i in resting}
    assert max(np.linalg.norm(out[i].T_w_c[:3, 3] - out[start].T_w_c[:3, 3]) for i in resting) < 1e-3
    sigma = np.array([np.sqrt(out[i].covariance[3, 3]) for i in resting])
    assert np.all(np.diff(sigma) > 0), sigma
    dt = scene.frames[resting[-1]].timestamp - scene.frames[resting[0]].timestamp
    rw = SETTINGS.rest.translation_random_walk
    assert sigma[-1] ** 2 - sigma[0] ** 2 == pytest.approx(rw ** 2 * dt, rel=1e-6)


def _still_imu(n: int, accel_offset=(0.0, 0.0, 0.0), seed: int = 0) -> ImuData:
    """``n`` samples at 200 Hz of a level IMU at rest (gravity along -z), datasheet white noise."""
    rng = np.random.default_rng(seed)
    base = ImuData(np.arange(2) / 200.0, np.zeros((2, 3)), np.zeros((2, 3)), np.eye(4))
    dt = 1 / 200.0
    gyro = base.gyro_noise / np.sqrt(dt) * rng.standard_normal((n, 3))
    accel = (np.array([0.0, 0.0, 9.81]) + np.asarray(accel_offset)
             + base.accel_noise / np.sqrt(dt) * rng.standard_normal((n, 3)))
    return replace(base, t=np.arange(n) * dt, gyro=gyro, accel=accel)


def test_zero_velocity_chi2_is_chi_square_at_rest_and_large_when_accelerating():
    """With the datasheet noise (multiplier 1) and exactly known biases and tilt (their sigmas
    ~0: nothing absorbed), 200 windows of 0.25 s of a resting IMU give a chi-square whose mean
    lies in the 99 % interval of the mean of 200 draws of chi2(dof); a constant 0.3 m/s^2
    acceleration (a camera reaching 3 cm/s in 0.1 s) fails the 0.99 quantile. The default
    multiplier (400: EuRoC's rotors shake the resting platform) is far more tolerant: it needs
    1 m/s^2 over 0.1 s; slower motion is left to the image tests (the creep tests above)."""
    s = RestSettings(imu_noise_multiplier=1.0, tilt_sigma_rad=1e-6, accel_bias_sigma=1e-6, gyro_bias_sigma=1e-6)
    values = []
    for seed in range(200):
        c, dof = zero_velocity_chi2(_still_imu(50, seed=seed), np.eye(3), np.zeros(3), np.zeros(3), s)
        values.append(c)
    trials = len(values)
    lo, hi = (chi2_distribution.ppf(q, dof * trials) / trials for q in (0.005, 0.995))
    assert lo < np.mean(values) < hi, (lo, np.mean(values), hi, dof)
    moving, dof = zero_velocity_chi2(_still_imu(50, accel_offset=(0.3, 0.0, 0.0)), np.eye(3), np.zeros(3),
                                     np.zeros(3), s)
    assert moving > chi2_distribution.ppf(0.99, dof)
    default = RestSettings()
    moving, dof = zero_velocity_chi2(_still_imu(20, accel_offset=(1.0, 0.0, 0.0)), np.eye(3), np.zeros(3),
                                     np.zeros(3), default)
    assert moving > chi2_distribution.ppf(default.chi2_probability, dof), moving


def test_a_sideways_motion_counts_only_beyond_the_rotation_uncertainty():
    """Keypoints of a random scene (depths 2-6 m) seen after a 1 cm motion, with the rotation
    exactly removed: along the view the motion is many sigma beyond 0.1 % of the depth whatever
    the rotation's uncertainty; sideways it is too with a sure rotation (0.1 mrad), not with an
    unsure one (10 mrad: a sideways motion of 1 cm at 4 m is a 2.5 mrad rotation). The rotation
    sigma grows with the gyroscope's scatter at rest."""
    from vio_depth.vio import anchor_motion, gyro_rotation_sigma

    rng = np.random.default_rng(3)
    cam = make_scene(duration_s=0.1).frames[0].camera
    uv = np.column_stack([rng.uniform(20, cam.width - 20, 400), rng.uniform(20, cam.height - 20, 400)])
    z = rng.uniform(2.0, 6.0, 400)
    p_ref = np.column_stack([(uv[:, 0] - cam.cx) / cam.fx * z, (uv[:, 1] - cam.cy) / cam.fy * z, z])
    for t, sure in (((0.0, 0.0, 0.01), True), ((0.01, 0.0, 0.0), False)):
        p_cur = p_ref - np.asarray(t)
        uv_cur, _ = cam.project(p_cur)
        sharp = anchor_motion(uv_cur + 0.3 * rng.standard_normal(uv.shape), uv, cam, np.eye(3), 1e-4)
        loose = anchor_motion(uv_cur + 0.3 * rng.standard_normal(uv.shape), uv, cam, np.eye(3), 1e-2)
        assert sharp.sigmas_beyond(0.001) > 5.0, t
        assert (loose.sigmas_beyond(0.001) > 5.0) == sure, (t, loose.sigmas_beyond(0.001))
    assert anchor_motion(uv_cur, uv_cur, cam, np.eye(3), 1e-2).sigmas_beyond(0.001) == 0.0
    settings = RestSettings()
    quiet, shaking = _still_imu(400), _still_imu(400)
    shaking = replace(shaking, gyro=shaking.gyro * 10.0)
    assert gyro_rotation_sigma(shaking, 2.0, settings) > 5 * gyro_rotation_sigma(quiet, 2.0, settings)
    assert gyro_rotation_sigma(quiet, 2.0, settings) > gyro_rotation_sigma(quiet, 1.0, settings)


def test_rest_settings_are_checked():
    with pytest.raises(SettingsError, match="chi2_probability"):
        RestSettings(chi2_probability=1.0)
    with pytest.raises(SettingsError, match="min_features"):
        RestSettings(min_features=2)
    with pytest.raises(SettingsError, match="translation_random_walk"):
        RestSettings(translation_random_walk=0.0)


EUROC = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "euroc_v101_static"


@pytest.mark.slow
def test_the_real_euroc_still_slice_is_held_still():
    """The real EuRoC V1_01 still slice (../shared/data, 95 frames; the platform stands with its
    rotors running: the ground truth turns ~4 mrad and moves 3.3 mm): after the static start at
    frame 21 every frame rests, within 1 cm of the start. The gyroscope scatters 6-7 mrad/s over
    0.05 s (8 times its datasheet) and its static-start bias is off by 1-2 mrad/s; a fixed 0.2 %
    motion test read that rotation as a sideways creep and ended the rest after 1.7 s (32 still,
    then 41 ``converging`` frames without a pose, up to 17.8 cm off). Measured now: 73 still,
    74/95 posed, largest move 0.04 cm. About 25 s (SIFT on 95 images)."""
    if not EUROC.is_dir():
        pytest.skip("../shared/data/euroc_v101_static absent")
    from matchers import create_matcher
    from vio_depth.io import open_sequence
    from vio_depth.vio import VioPoseSource

    seq = open_sequence(EUROC)
    matcher = create_matcher("sift")
    src = VioPoseSource(seq.imu, matcher, SETTINGS)
    out = [src.track(f, matcher.extract(f.image())) for f in seq]
    start = next(i for i, p in enumerate(out) if p.ok)
    assert start <= 25, out[start].reason
    after = [p.status for p in out[start + 1:]]
    assert all(s == VioStatus.STILL for s in after), [(i, p.status.value, p.reason) for i, p in enumerate(out)
                                                     if i > start and p.status != VioStatus.STILL][:3]
    posed = [T for T in (src.world_pose(f) for f in seq) if T is not None]
    assert len(posed) >= 74
    moves = np.linalg.norm(np.stack([T[:3, 3] for T in posed]) - posed[0][:3, 3], axis=1)
    assert moves.max() < 0.01, moves.max()
