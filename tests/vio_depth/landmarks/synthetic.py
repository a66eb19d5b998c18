"""Synthetic scenes of known truth for the landmark tests: a camera moving sideways in
front of a textured box of points, exact projections plus pixel noise, and noisy pose
priors drawn inside their stated uncertainty."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from matchers.base import Features, Matches
from vio_core.camera import Camera
from vio_core.geometry import make_transform

CAMERA = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


@dataclass
class Scene:
    points_w: np.ndarray  # (P, 3) metres
    T_w_c: np.ndarray  # (F, 4, 4) true poses
    T_prior: np.ndarray  # (F, 4, 4) noisy priors
    features: list  # per frame Features; descriptor = one-hot point id (matched by id)
    ids: list  # per frame (N,) point id of each keypoint
    outlier: list  # per frame (N,) bool: keypoint moved by 20-60 px (a wrong match)
    camera: Camera

    def depth_of(self, frame: int, ids) -> np.ndarray:
        """(N,) metres: true depth of points ``ids`` in frame ``frame``."""
        T = self.T_w_c[frame]
        return ((self.points_w[ids] - T[:3, 3]) @ T[:3, :3])[:, 2]


def make_scene(n_frames=24, n_points=600, step_m=0.05, depth=(2.0, 6.0), pixel_sigma=0.7,
               prior_rot_deg=0.0, prior_trans_m=0.0, seed=0, camera: Camera = CAMERA,
               outlier_fraction=0.0, hold_frames=0, hold_rotation_deg=0.0) -> Scene:
    """A sideways-moving camera (``step_m`` per frame, slight rotation wobble).

    Prior errors: each pose gets an independent rotation error of ``prior_rot_deg`` and
    translation error of ``prior_trans_m`` (1-sigma per axis). ``outlier_fraction`` of
    the observations are moved by 20-60 px (wrong matches). ``hold_frames`` more frames
    follow at the last position (a stop), each turned by ``hold_rotation_deg`` about the
    vertical axis from the previous one (0: standing still; else a pure rotation).
    """
    rng = np.random.default_rng(seed)
    T_true, T_prior = [], []
    for k in range(n_frames):
        R = Rotation.from_rotvec([0.02 * np.sin(0.3 * k), 0.03 * np.sin(0.2 * k), 0.01 * k / n_frames]).as_matrix()
        T_true.append(make_transform(R, np.array([step_m * k, 0.02 * np.sin(0.5 * k), 0.01 * k])))
        dR = Rotation.from_rotvec(np.radians(prior_rot_deg) * rng.normal(size=3)).as_matrix()
        T_prior.append(make_transform(R @ dR, T_true[-1][:3, 3] + prior_trans_m * rng.normal(size=3)))
    for _ in range(hold_frames):
        last = T_true[-1]
        R = last[:3, :3] @ Rotation.from_rotvec([0.0, np.radians(hold_rotation_deg), 0.0]).as_matrix()
        T_true.append(make_transform(R, last[:3, 3]))
        dR = Rotation.from_rotvec(np.radians(prior_rot_deg) * rng.normal(size=3)).as_matrix()
        T_prior.append(make_transform(R @ dR, last[:3, 3] + prior_trans_m * rng.normal(size=3)))
    T_true, T_prior = np.array(T_true), np.array(T_prior)
    n_frames = len(T_true)
    mid = T_true[n_frames // 2]
    z = rng.uniform(*depth, n_points)
    uv = np.column_stack([rng.uniform(0, camera.width, n_points), rng.uniform(0, camera.height, n_points)])
    p_c = np.column_stack([(uv[:, 0] - camera.cx) / camera.fx * z, (uv[:, 1] - camera.cy) / camera.fy * z, z])
    points = p_c @ mid[:3, :3].T + mid[:3, 3]
    feats, ids, outliers = [], [], []
    for k in range(n_frames):
        T = T_true[k]
        pc = (points - T[:3, 3]) @ T[:3, :3]
        ideal, zz = camera.project(pc)
        ok = (zz > 0) & camera.in_image(ideal, margin=2)
        idx = np.nonzero(ok)[0]
        obs = camera.distort_points(ideal[idx]) + pixel_sigma * rng.normal(size=(len(idx), 2))
        bad = rng.random(len(idx)) < outlier_fraction
        obs[bad] += rng.uniform(20, 60, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
        perm = rng.permutation(len(idx))
        idx, obs, bad = idx[perm], obs[perm], bad[perm]
        outliers.append(bad)
        desc = np.zeros((len(idx), 1), np.float32)
        desc[:, 0] = idx
        feats.append(Features(obs.astype(np.float32), desc, np.ones(len(idx), np.float32), (camera.width, camera.height)))
        ids.append(idx)
    return Scene(points, T_true, T_prior, feats, ids, outliers, camera)


class IdMatcher:
    """Matches features by the point id stored as their descriptor (perfect matching)."""

    name = "ids"

    def match(self, a: Features, b: Features) -> Matches:
        ia, ib = a.descriptors[:, 0].astype(np.int64), b.descriptors[:, 0].astype(np.int64)
        _, pa, pb = np.intersect1d(ia, ib, return_indices=True)
        return Matches(pa.astype(np.int64), pb.astype(np.int64), np.ones(len(pa), np.float32))
