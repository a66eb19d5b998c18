"""Synthetic visual-inertial scenes of known truth for the VIO tests.

A hand-held camera (sums of sinusoids, like the room sample's trajectory) or a
still-then-moving one in a 6 x 5 x 3 m box whose walls, floor and ceiling carry random
points; exact projections plus pixel noise become :class:`matchers.Features` whose
descriptor is the point id (:class:`IdMatcher` matches them perfectly); the IMU is
SIMULATED from the trajectory (:func:`vio_depth.simulate.imu.simulate_imu`, EuRoC-like
noise, seeded). Nothing is rendered: a run takes seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from matchers.base import Features, Matches
from vio_core.camera import Camera
from vio_core.geometry import invert_transform
from vio_depth.frame import Frame, ImuData
from vio_depth.simulate.generate import camera_mount
from vio_depth.simulate.imu import ImuNoise, simulate_imu
from vio_depth.simulate.trajectory import Sinusoids, SinusoidTrajectory

CAMERA = Camera(512, 384, 420.0, 420.0, 255.5, 191.5)
T_I_C = camera_mount([0.03, -0.05, 0.02], yaw_deg=-1.0, pitch_deg=2.0, roll_deg=1.5)


@dataclass
class VioScene:
    """Frames, features, IMU and the truth of one synthetic run."""

    frames: list  # Frame, with the true T_w_c (the estimator must not read it)
    features: list  # Features per frame
    ids: list  # (N,) point id of each keypoint, per frame
    imu: ImuData
    T_w_c: np.ndarray  # (F, 4, 4) true camera poses
    v_w: np.ndarray  # (F, 3) true IMU velocities
    points_w: np.ndarray
    gyro_bias: np.ndarray  # (3,) true initial gyro bias
    imu_truth_R_w_i: np.ndarray  # (M, 3, 3) true IMU orientation at every IMU sample
    camera: Camera = CAMERA

    def path_length(self, upto: int | None = None) -> float:
        p = self.T_w_c[:upto, :3, 3]
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def _room_points(rng, n: int) -> np.ndarray:
    """``n`` random points on the walls, floor and ceiling of the box [0, 6] x [0, 5] x [0, 3] m."""
    face = rng.integers(0, 6, n)
    u, v = rng.random(n), rng.random(n)
    p = np.column_stack([6 * u, 5 * v, 3 * rng.random(n)])
    p[face == 0, 0] = 0.0
    p[face == 1, 0] = 6.0
    p[face == 2, 1] = 0.0
    p[face == 3, 1] = 5.0
    p[face == 4, 2] = 0.0
    p[face == 5, 2] = 3.0
    return p


def hand_held(still_s: float = 0.0) -> SinusoidTrajectory:
    """A walk across the box while panning (like the room sample); at rest for ``still_s`` seconds
    first, then starting smoothly (:class:`_StillThen`)."""
    rng = np.random.default_rng(7)
    phase = rng.uniform(0, 2 * np.pi, (6, 3))
    amp = np.array([[0.08, 0.03, 0.003], [0.08, 0.025, 0.003], [0.06, 0.02, 0.002]])
    freq = np.array([[0.13, 0.7, 2.3], [0.11, 0.8, 2.1], [0.17, 0.9, 2.7]])
    e_amp = np.array([[0.15, 0.04, 0.004], [0.3, 0.04, 0.003], [0.05, 0.02, 0.002]])
    e_freq = np.array([[0.15, 0.6, 2.5], [0.12, 0.5, 2.2], [0.2, 0.7, 2.9]])
    position = Sinusoids([1.0, 0.9, 1.4], [0.45, 0.4, 0.0], amp, freq, phase[:3])
    euler = Sinusoids([0.7, 0.1, 0.0], [0.4, 0.0, 0.0], e_amp, e_freq, phase[3:])
    traj = SinusoidTrajectory(position, euler, 0.0, 20.0)
    if still_s <= 0:
        return traj
    return _StillThen(traj, still_s)


class _StillThen(SinusoidTrajectory):
    """``traj`` time-warped (``tau(t)``) so that it rests until ``still_s`` and then starts smoothly."""

    def __init__(self, traj: SinusoidTrajectory, still_s: float, ramp_s: float = 1.0):
        super().__init__(traj.position, traj.euler, traj.t_start, traj.t_end)
        self.still_s, self.ramp_s = float(still_s), float(ramp_s)

    def _tau(self, t):
        """Warped time and its first two time derivatives: ``tau' = h(x)``, ``h`` the quintic
        smoothstep of ``x = (t - still_s) / ramp_s`` (0 before, 1 after the ramp): at rest until
        ``still_s``, continuous velocity and acceleration."""
        r = self.ramp_s
        x = np.clip((t - self.still_s) / r, 0.0, None)
        xi = np.minimum(x, 1.0)
        tau = np.where(x < 1.0, r * (xi**6 - 3 * xi**5 + 2.5 * xi**4), r * (0.5 + x - 1.0))
        d1 = np.where(x < 1.0, 6 * xi**5 - 15 * xi**4 + 10 * xi**3, 1.0)
        d2 = np.where(x < 1.0, (30 * xi**4 - 60 * xi**3 + 30 * xi**2) / r, 0.0)
        return tau, d1, d2

    def _warp(self, f, t, order):
        tau, d1, d2 = self._tau(t)
        if order == 0:
            return f(tau, 0)
        if order == 1:
            return f(tau, 1) * d1[:, None]
        return f(tau, 2) * (d1**2)[:, None] + f(tau, 1) * d2[:, None]

    def _position(self, t, order):
        return self._warp(self.position, t, order)

    def _euler(self, t, order):
        return self._warp(self.euler, t, order)


def creeping(speed_m_s: float, still_s: float, direction_w=(0.6, 0.8, 0.0), ramp_s: float = 0.5) -> SinusoidTrajectory:
    """A camera that rests until ``still_s``, then creeps along a straight line in the world
    direction ``direction_w`` (normalised) at ``speed_m_s``, reached smoothly over ``ramp_s``;
    its orientation is constant (yaw 0.7 rad: it looks across the box, at a mix of the walls)."""
    d = np.asarray(direction_w, float)
    d = d / np.linalg.norm(d)
    flat = np.zeros((3, 1))
    position = Sinusoids([1.0, 0.9, 1.4], speed_m_s * d, flat, flat, flat)
    euler = Sinusoids([0.7, 0.1, 0.0], [0.0, 0.0, 0.0], flat, flat, flat)
    return _StillThen(SinusoidTrajectory(position, euler, 0.0, 60.0), still_s, ramp_s)


def make_scene(duration_s: float = 4.0, rate_hz: float = 20.0, n_points: int = 3000, pixel_sigma: float = 0.5,
               still_s: float = 0.0, seed: int = 0, imu_noise: ImuNoise | None = ImuNoise(),
               trajectory: SinusoidTrajectory | None = None) -> VioScene:
    """A synthetic run (module docstring): frames from t = 0.5 s, IMU at 200 Hz from t = 0;
    the hand-held walk (:func:`hand_held`) unless ``trajectory`` is given."""
    rng = np.random.default_rng(seed)
    traj = hand_held(still_s) if trajectory is None else trajectory
    t_imu = np.arange(int(round((duration_s + 1.0) * 200)) + 1) / 200.0
    imu, truth = simulate_imu(traj, t_imu, invert_transform(T_I_C), noise=imu_noise, seed=seed)
    t_frames = 0.5 + np.arange(int(round(duration_s * rate_hz))) / rate_hz
    st = traj.state(t_frames)
    T_w_c = st.T_w_i() @ T_I_C
    points = _room_points(rng, n_points)
    frames, feats, ids = [], [], []
    for k, (t, T) in enumerate(zip(t_frames, T_w_c)):
        pc = (points - T[:3, 3]) @ T[:3, :3]
        uv, z = CAMERA.project(pc)
        ok = (z > 0.2) & CAMERA.in_image(uv, margin=2)
        idx = np.nonzero(ok)[0]
        obs = uv[idx] + pixel_sigma * rng.normal(size=(len(idx), 2))
        perm = rng.permutation(len(idx))
        idx, obs = idx[perm], obs[perm]
        desc = idx.astype(np.float32)[:, None]
        feats.append(Features(obs.astype(np.float32), desc, np.ones(len(idx), np.float32),
                              (CAMERA.width, CAMERA.height)))
        ids.append(idx)
        frames.append(Frame(k, float(t), f"{k:06d}", CAMERA, T.copy(), load_image=_no_image))
    return VioScene(frames, feats, ids, imu, T_w_c, st.v_w, points, truth["gyro_bias"][0], traj.state(t_imu).R_w_i)


def _no_image():
    raise AssertionError("synthetic frames have no image")


class IdMatcher:
    """Matches features by the point id stored as their descriptor (perfect matching)."""

    name = "ids"

    def extract(self, image):
        raise AssertionError("synthetic frames have no image")

    def match(self, a: Features, b: Features) -> Matches:
        ia, ib = a.descriptors[:, 0].astype(np.int64), b.descriptors[:, 0].astype(np.int64)
        _, pa, pb = np.intersect1d(ia, ib, return_indices=True)
        return Matches(pa.astype(np.int64), pb.astype(np.int64), np.ones(len(pa), np.float32))
