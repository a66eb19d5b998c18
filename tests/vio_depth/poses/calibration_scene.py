"""The synthetic scene of the pose-calibration tests (tests/vio_depth/poses/test_calibration.py,
tests/vio_depth/run/test_pose_calibration.py): 4000 random 3D points 2-7 m in front of a
camera (no rendering), 25 Hz frames, the camera rotating fast about three axes (up to 30 deg
amplitude at 0.7-1.1 Hz: peaks of 130-160 deg/s) while moving ~0.3 m/s; the sequence's poses
are those of a body: ``T_w_b(t) = T_w_c(t - dt) T_b_c^-1``.
"""

import math

import numpy as np
from scipy.spatial.transform import Rotation

from matchers import Features, Matches
from vio_core import Camera
from vio_depth.poses import PairMatches

CAM = Camera(640, 480, 500.0, 500.0, 319.5, 239.5)
RATE_HZ = 25.0
TRUE_DT = 0.015
TRUE_T_B_C = np.eye(4)
TRUE_T_B_C[:3, :3] = Rotation.from_rotvec(np.radians(2.0) * np.array([1.0, 2.0, 2.0]) / 3.0).as_matrix()
TRUE_T_B_C[:3, 3] = [0.03, 0.0, 0.0]


def camera_trajectory(t, rotation_amp_deg=(30.0, 25.0, 15.0)) -> np.ndarray:
    """(K, 4, 4) camera-to-world poses at ``t`` seconds: sinusoidal rotation about three axes,
    a slow sway and 0.3 m/s forward."""
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    euler = np.stack([math.radians(a) * np.sin(2 * np.pi * f * t + ph)
                      for a, f, ph in zip(rotation_amp_deg, (0.7, 0.9, 1.1), (0.3, 1.1, 2.0))], axis=1)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("yxz", euler).as_matrix()
    T[:, :3, 3] = np.stack([0.15 * np.sin(np.pi * t), 0.1 * np.sin(1.6 * np.pi * t + 1), 0.3 * t], axis=1)
    return T


def scene(dt=TRUE_DT, T_b_c=TRUE_T_B_C, rotation_amp_deg=(30.0, 25.0, 15.0), n=60, seed=0):
    """``(timestamps, camera poses, body poses, points)`` of the synthetic sequence."""
    rng = np.random.default_rng(seed)
    ts = 1.0 + np.arange(n) / RATE_HZ
    T_w_c = camera_trajectory(ts, rotation_amp_deg)
    T_w_b = camera_trajectory(ts - dt, rotation_amp_deg) @ np.linalg.inv(T_b_c)
    points = np.column_stack([rng.uniform(-6, 6, 4000), rng.uniform(-5, 5, 4000), rng.uniform(2, 7, 4000)])
    return ts, T_w_c, T_w_b, points


def project(T_w_c, points):
    """``(uv (N, 2), visible (N,))`` of ``points`` in the camera at ``T_w_c``."""
    p_c = (points - T_w_c[:3, 3]) @ T_w_c[:3, :3]
    uv = p_c[:, :2] / p_c[:, 2:3] * CAM.fx + [CAM.cx, CAM.cy]
    visible = (p_c[:, 2] > 0.3) & np.all((uv >= 0) & (uv < [CAM.width, CAM.height]), axis=1)
    return uv, visible


def synthetic_pairs(ts, T_w_c, points, seed=0, noise_px=0.5, outliers=0.05):
    rng = np.random.default_rng(seed + 1)
    pairs = []
    for i in range(0, len(ts) - 5, 2):
        for gap in (3, 5):
            j = i + gap
            (ua, va), (ub, vb) = project(T_w_c[i], points), project(T_w_c[j], points)
            both = np.flatnonzero(va & vb)
            idx = rng.choice(both, min(200, len(both)), replace=False)
            a = ua[idx] + rng.normal(0, noise_px, (len(idx), 2))
            b = ub[idx] + rng.normal(0, noise_px, (len(idx), 2))
            wrong = int(outliers * len(idx))
            b[:wrong] = rng.uniform([0, 0], [CAM.width, CAM.height], (wrong, 2))
            pairs.append(PairMatches(ts[i], ts[j], a, b, CAM, CAM, i, j))
    return pairs


def rotation_error_deg(T_a, T_b) -> float:
    return math.degrees(float(np.linalg.norm(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).as_rotvec())))


class IdMatcher:
    """A matcher whose 'images' are frame indices: the keypoints are the synthetic scene's
    projections (0.5 px noise), matched by point id."""

    name = "ids"

    def __init__(self, T_w_c, points):
        self.T_w_c, self.points = T_w_c, points
        self.extracted: list[int] = []

    def extract(self, image):
        i = int(image[0, 0, 0])
        self.extracted.append(i)
        uv, visible = project(self.T_w_c[i], self.points)
        ids = np.flatnonzero(visible)
        rng = np.random.default_rng(i)
        kp = (uv[ids] + rng.normal(0, 0.5, (len(ids), 2))).astype(np.float32)
        return Features(kp, ids[:, None].astype(np.float32), np.ones(len(ids), np.float32), (CAM.width, CAM.height))

    def match(self, a, b):
        common, ia, ib = np.intersect1d(a.descriptors[:, 0], b.descriptors[:, 0], return_indices=True)
        return Matches(ia.astype(np.int64), ib.astype(np.int64), np.ones(len(common), np.float32))
