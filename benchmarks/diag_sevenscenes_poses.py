"""Diagnosis: how consistent are 7-Scenes' KinectFusion poses with its colour images?

For frame pairs ``(i, i - gap)`` of ``DATA/7scenes_redkitchen`` (SIFT matches, the loader's
colour camera and registered Kinect depth), per 30-frame bin:

* ``d2d``: median relative error of frame i's Kinect depth moved into frame i-gap with the
  KinectFusion poses against that frame's depth
  (:func:`vio_depth.evaluation.depth_reprojection_errors`): do poses and depth agree?
* ``pnp dt`` / ``pnp dR``: difference between the KinectFusion relative pose and the one
  that PnP (RANSAC + LM) finds from frame i's Kinect depth at its keypoints and their
  matches in the colour image of frame i-gap (millimetres / degrees): do poses and
  colour images agree?
* ``|t|``: the KinectFusion translation of the pair (mm);
* ``best dt frames``: the time shift of frame i-gap along the (interpolated) KinectFusion
  trajectory, within +-``--max-shift`` frames, that brings the trajectory closest to the
  PnP pose, and the remaining difference: is a colour/depth time offset the cause?

Run: ``python benchmarks/diag_sevenscenes_poses.py [--data DIR] [--gap 6] [--step 5]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def main(argv=None) -> int:
    import cv2
    from scipy.spatial.transform import Rotation, Slerp

    from matchers import create_matcher
    from vio_core.geometry import invert_transform, relative_transform, rotation_angle_deg
    from vio_depth.evaluation import depth_reprojection_errors
    from vio_depth.evaluation.point_accuracy import window_median_depth
    from vio_depth.io import open_sequence

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO / ".." / "shared" / "data")
    ap.add_argument("--gap", type=int, default=6)
    ap.add_argument("--step", type=int, default=5)
    ap.add_argument("--max-shift", type=float, default=3.0)
    args = ap.parse_args(argv)
    seq = open_sequence(args.data / "7scenes_redkitchen")
    cam, n = seq.camera, len(seq)
    Tw = np.array([seq[i].T_w_c for i in range(n)])
    slerp = Slerp(np.arange(n), Rotation.from_matrix(Tw[:, :3, :3]))

    def pose_at(x):
        x = float(np.clip(x, 0, n - 1 - 1e-9))
        i0, a = int(np.floor(x)), x - np.floor(x)
        T = np.eye(4)
        T[:3, :3] = slerp([x]).as_matrix()[0]
        T[:3, 3] = (1 - a) * Tw[i0, :3, 3] + a * Tw[i0 + 1, :3, 3]
        return T

    matcher = create_matcher("sift")
    rows = []
    feats = {}
    for i in range(args.gap, n, args.step):
        j = i - args.gap
        for k in (i, j):
            if k not in feats:
                feats[k] = matcher.extract(seq[k].image())
        m = matcher.match(feats[i], feats[j])
        ua = feats[i].keypoints[m.idx_a].astype(float)
        ub = feats[j].keypoints[m.idx_b].astype(float)
        gt_i = seq[i].gt_depth()
        T_j_i = relative_transform(Tw[j], Tw[i])
        d2d = float(np.median(depth_reprojection_errors(gt_i, seq[j].gt_depth(), cam, T_j_i)))
        z = window_median_depth(ua, gt_i, 1)
        ok = np.isfinite(z) & (z > 0.3)
        P = cam.backproject(ua[ok], z[ok])
        found, rvec, tvec, inl = cv2.solvePnPRansac(P, ub[ok], cam.K, None, reprojectionError=2.0,
                                                    iterationsCount=500, flags=cv2.SOLVEPNP_EPNP)
        if not found or inl is None or len(inl) < 40:
            continue
        inl = inl.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(P[inl], ub[ok][inl], cam.K, None, rvec, tvec)
        T_pnp = np.eye(4)
        T_pnp[:3, :3] = cv2.Rodrigues(rvec)[0]
        T_pnp[:3, 3] = tvec.ravel()
        T_i_j_pnp = invert_transform(T_pnp)  # colour camera j in camera i
        T_i_j = invert_transform(T_j_i)
        dt = np.linalg.norm(T_i_j[:3, 3] - T_i_j_pnp[:3, 3]) * 1000
        dR = rotation_angle_deg(T_i_j[:3, :3].T @ T_i_j_pnp[:3, :3])
        shifts = np.arange(-args.max_shift, args.max_shift + 1e-9, 0.25)
        err = [np.linalg.norm(relative_transform(Tw[i], pose_at(j + s))[:3, 3] - T_i_j_pnp[:3, 3]) * 1000
               for s in shifts]
        b = int(np.argmin(err))
        rows.append((i, d2d, dt, dR, np.linalg.norm(T_j_i[:3, 3]) * 1000, shifts[b], err[b]))
    rows = np.array(rows)
    print(f"7-Scenes redkitchen, pairs (i, i-{args.gap}) every {args.step} frames; medians per 30-frame bin")
    print(f"{'frames':>9s} {'pairs':>5s} {'d2d':>7s} {'|t| mm':>7s} {'pnp dt mm':>9s} {'pnp dR deg':>10s} "
          f"{'best shift':>10s} {'left mm':>7s}")
    for b0 in range(0, n, 30):
        sel = (rows[:, 0] >= b0) & (rows[:, 0] < b0 + 30)
        if not sel.any():
            continue
        r = rows[sel]
        print(f"{b0:4d}-{b0 + 29:<4d} {sel.sum():5d} {np.median(r[:, 1]):7.4f} {np.median(r[:, 4]):7.1f} "
              f"{np.median(r[:, 2]):9.1f} {np.median(r[:, 3]):10.2f} {np.median(r[:, 5]):+10.2f} {np.median(r[:, 6]):7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
