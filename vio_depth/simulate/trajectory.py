"""Smooth analytic body (IMU) trajectories with exact derivatives.

A trajectory gives, for any time, the IMU pose ``T_w_i`` (world z up, metres), the
world velocity and acceleration of the IMU origin and the body angular rate in the IMU
frame, all *analytically*, so that simulated IMU samples are exactly consistent with the
poses. The IMU (body) frame is x forward, y left, z up; its orientation is given by
ZYX Euler angles ``R_w_i = Rz(yaw) Ry(pitch) Rx(roll)``, whose body rate is

    omega_i = [roll' - yaw' sin(pitch),
               pitch' cos(roll) + yaw' cos(pitch) sin(roll),
               yaw' cos(pitch) cos(roll) - pitch' sin(roll)].

Two kinds are provided:

* :class:`SinusoidTrajectory`: position and Euler angles are each a line plus a sum of
  sinusoids (hand-held motion);
* :class:`DrivingTrajectory`: the horizontal position is a quintic interpolating
  B-spline (C4) of a planned path, the heading follows the velocity direction
  (a car does not slip), height, pitch and roll are small sinusoidal oscillations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from vio_core.checks import check_array
from vio_core.errors import InputError


@dataclass(frozen=True)
class TrajectoryState:
    """Trajectory samples at K times.

    Attributes:
        t: (K,) seconds.
        R_w_i: (K, 3, 3) IMU-to-world rotations.
        p_w: (K, 3) metres, IMU origin in the world.
        v_w: (K, 3) m/s world velocity.
        a_w: (K, 3) m/s^2 world acceleration (kinematic, without gravity).
        omega_i: (K, 3) rad/s angular rate in the IMU frame.
    """

    t: np.ndarray
    R_w_i: np.ndarray
    p_w: np.ndarray
    v_w: np.ndarray
    a_w: np.ndarray
    omega_i: np.ndarray

    def T_w_i(self) -> np.ndarray:
        """(K, 4, 4) IMU-to-world transforms."""
        T = np.tile(np.eye(4), (len(self.t), 1, 1))
        T[:, :3, :3] = self.R_w_i
        T[:, :3, 3] = self.p_w
        return T


@dataclass(frozen=True)
class Sinusoids:
    """Vector signal ``f(t) = offset + rate t + sum_k amp_k sin(2 pi freq_k t + phase_k)``.

    Attributes:
        offset, rate: (D,) value and slope per component.
        amp, freq, phase: (D, K) amplitudes, frequencies (Hz) and phases (rad).
    """

    offset: np.ndarray
    rate: np.ndarray
    amp: np.ndarray
    freq: np.ndarray
    phase: np.ndarray

    def __post_init__(self):
        off = check_array("offset", self.offset, (None,), finite=True)
        d = len(off)
        amp = check_array("amp", self.amp, (d, None), finite=True)
        object.__setattr__(self, "offset", off.astype(np.float64))
        object.__setattr__(self, "rate", check_array("rate", self.rate, (d,), finite=True).astype(np.float64))
        object.__setattr__(self, "amp", amp.astype(np.float64))
        object.__setattr__(self, "freq", check_array("freq", self.freq, amp.shape, finite=True).astype(np.float64))
        object.__setattr__(self, "phase", check_array("phase", self.phase, amp.shape, finite=True).astype(np.float64))

    def __call__(self, t, order: int = 0) -> np.ndarray:
        """``order``-th time derivative (0, 1 or 2) at ``t: (K,)`` seconds -> (K, D)."""
        t = check_array("t", t, (None,), finite=True)[:, None, None]
        w = 2.0 * np.pi * self.freq[None]
        arg = w * t + self.phase[None]
        amp = self.amp[None]
        tt = t[:, :, 0]
        if order == 0:
            return self.offset[None] + self.rate[None] * tt + (amp * np.sin(arg)).sum(-1)
        if order == 1:
            return np.broadcast_to(self.rate[None], (len(tt), len(self.rate))) + (amp * w * np.cos(arg)).sum(-1)
        if order == 2:
            return -(amp * w * w * np.sin(arg)).sum(-1)
        raise InputError(f"order must be 0, 1 or 2, got {order}")


def euler_zyx_to_matrix(euler) -> np.ndarray:
    """``euler: (K, 3)`` (yaw, pitch, roll) rad -> (K, 3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    e = check_array("euler", euler, (None, 3))
    cy, sy = np.cos(e[:, 0]), np.sin(e[:, 0])
    cp, sp = np.cos(e[:, 1]), np.sin(e[:, 1])
    cr, sr = np.cos(e[:, 2]), np.sin(e[:, 2])
    R = np.empty((len(e), 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    return R


def euler_zyx_body_rate(euler, euler_rate) -> np.ndarray:
    """Body angular rate (K, 3) rad/s from ``euler, euler_rate: (K, 3)`` (yaw, pitch, roll) and rates."""
    e = check_array("euler", euler, (None, 3))
    d = check_array("euler_rate", euler_rate, (len(e), 3))
    _, p, r = e.T
    dy, dp, dr = d.T
    return np.stack([
        dr - dy * np.sin(p),
        dp * np.cos(r) + dy * np.cos(p) * np.sin(r),
        dy * np.cos(p) * np.cos(r) - dp * np.sin(r),
    ], axis=1)


class Trajectory:
    """Base class: subclasses implement ``_position(t, order)`` and ``_euler(t, order)``
    (order 0 and 1 for the angles, 0..2 for the position), each returning (K, 3)."""

    t_start: float
    t_end: float

    def _position(self, t: np.ndarray, order: int) -> np.ndarray:
        raise NotImplementedError

    def _euler(self, t: np.ndarray, order: int) -> np.ndarray:
        raise NotImplementedError

    def state(self, t) -> TrajectoryState:
        """Exact state at ``t: (K,)`` seconds (within [t_start, t_end])."""
        t = check_array("t", np.atleast_1d(t), (None,), finite=True)
        if len(t) and (t.min() < self.t_start - 1e-9 or t.max() > self.t_end + 1e-9):
            raise InputError(f"times must lie in [{self.t_start}, {self.t_end}] s")
        e = self._euler(t, 0)
        return TrajectoryState(
            t=t, R_w_i=euler_zyx_to_matrix(e), p_w=self._position(t, 0), v_w=self._position(t, 1),
            a_w=self._position(t, 2), omega_i=euler_zyx_body_rate(e, self._euler(t, 1)),
        )

    def T_w_i(self, t) -> np.ndarray:
        """(K, 4, 4) IMU-to-world poses at ``t: (K,)`` seconds."""
        return self.state(t).T_w_i()


class SinusoidTrajectory(Trajectory):
    """Position and (yaw, pitch, roll) are :class:`Sinusoids` of time (hand-held motion)."""

    def __init__(self, position: Sinusoids, euler: Sinusoids, t_start: float, t_end: float):
        if len(position.offset) != 3 or len(euler.offset) != 3:
            raise InputError("position and euler must have 3 components")
        self.position, self.euler = position, euler
        self.t_start, self.t_end = float(t_start), float(t_end)

    def _position(self, t, order):
        return self.position(t, order)

    def _euler(self, t, order):
        return self.euler(t, order)


class DrivingTrajectory(Trajectory):
    """Car-like motion: planar quintic spline path, yaw along the velocity.

    Args:
        t_knots: (K,) seconds, strictly increasing sample times of the planned path.
        xy: (K, 2) metres, planned positions; they are interpolated by a quintic B-spline
            (``scipy.interpolate.make_interp_spline``, k = 5), which *is* the trajectory.
        height: Sinusoids with one component: IMU height z (m).
        pitch_roll: Sinusoids with two components: pitch and roll (rad).
    """

    def __init__(self, t_knots, xy, height: Sinusoids, pitch_roll: Sinusoids):
        t_knots = check_array("t_knots", t_knots, (None,), finite=True)
        xy = check_array("xy", xy, (len(t_knots), 2), finite=True)
        if np.any(np.diff(t_knots) <= 0):
            raise InputError("t_knots must be strictly increasing")
        if len(height.offset) != 1 or len(pitch_roll.offset) != 2:
            raise InputError("height needs 1 component and pitch_roll 2")
        self.spline = make_interp_spline(t_knots, xy, k=5)
        self._d = [self.spline, self.spline.derivative(1), self.spline.derivative(2)]
        self.height, self.pitch_roll = height, pitch_roll
        self.t_start, self.t_end = float(t_knots[0]), float(t_knots[-1])

    def _position(self, t, order):
        return np.concatenate([self._d[order](t), self.height(t, order)], axis=1)

    def _euler(self, t, order):
        v = self._d[1](t)
        pr = self.pitch_roll(t, order)
        if order == 0:
            yaw = np.arctan2(v[:, 1], v[:, 0])
        else:
            a = self._d[2](t)
            yaw = (v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]) / np.maximum(np.einsum("ki,ki->k", v, v), 1e-12)
        return np.concatenate([yaw[:, None], pr], axis=1)


def smoothstep(x) -> np.ndarray:
    """Quintic smoothstep ``6x^5 - 15x^4 + 10x^3`` on [0, 1] (clamped outside); C2."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def plan_drive(speed, curvature, t, *, start_xy=(0.0, 0.0), start_heading: float = 0.0,
               substeps: int = 200) -> np.ndarray:
    """Integrate a planar path: positions ``(K, 2)`` m at ``t: (K,)`` s (t[0] at ``start_xy``).

    ``speed(t)`` (m/s) and ``curvature(s)`` (1/m, positive = left turn, of arc length s)
    are vectorised callables; integration uses ``substeps`` midpoint steps per interval.
    """
    t = check_array("t", t, (None,), finite=True)
    fine = np.linspace(t[0], t[-1], (len(t) - 1) * substeps + 1)
    dt = np.diff(fine)
    mid = 0.5 * (fine[1:] + fine[:-1])
    ds = speed(mid) * dt
    s = np.concatenate([[0.0], np.cumsum(ds)])
    s_mid = 0.5 * (s[1:] + s[:-1])
    # heading at the step midpoints: integrate curvature over arc length on the same grid
    kappa = curvature(s_mid)
    heading_nodes = start_heading + np.concatenate([[0.0], np.cumsum(kappa * ds)])
    heading_mid = 0.5 * (heading_nodes[1:] + heading_nodes[:-1])
    x = start_xy[0] + np.concatenate([[0.0], np.cumsum(np.cos(heading_mid) * ds)])
    y = start_xy[1] + np.concatenate([[0.0], np.cumsum(np.sin(heading_mid) * ds)])
    return np.stack([x, y], axis=1)[::substeps]
