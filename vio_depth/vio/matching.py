"""Matches for the odometry: the pipeline's matcher, then an epipolar RANSAC gate; and the
rotation-free image motion of a pair (:func:`rotation_free_flow`).

Repeated textures (brick walls, tiled floors) give nearest-neighbour matches that look
right but belong to the neighbouring brick. A projection factor that carries one pulls
the poses the IMU has to follow; a fundamental-matrix RANSAC over each pair's matches
(as VINS-Mono does on its optical-flow tracks) removes the matches that disagree with the
pair's dominant motion. Keypoints are undistorted first (the gate needs pinhole rays).
"""

from __future__ import annotations

import cv2
import numpy as np

from matchers import Features, Matcher, Matches
from vio_core.camera import Camera
from vio_core.checks import check_array


def rotation_free_displacements(kp_cur, kp_prev, camera_cur: Camera, camera_prev: Camera, R_prev_cur) -> np.ndarray:
    """Pixel motion of each matched keypoint once the camera's rotation is removed.

    Args:
        kp_cur: (N, 2) raw pixels in the current image. kp_prev: (N, 2) raw pixels of the
            same points in the previous image.
        camera_cur, camera_prev: their cameras (keypoints are undistorted first).
        R_prev_cur: (3, 3) rotation of the current camera into the previous one (e.g. from
            the gyroscope).

    Returns:
        (K,) distances (pixels of ``camera_prev``) between the previous keypoints and the
        current ones rotated into the previous image, for the K <= N rays in front of the
        previous camera.
    """
    kp_cur = check_array("kp_cur", kp_cur, (None, 2))
    kp_prev = check_array("kp_prev", kp_prev, (len(kp_cur), 2))
    R = check_array("R_prev_cur", R_prev_cur, (3, 3), finite=True)
    ic = camera_cur.undistort_points(np.asarray(kp_cur, float))
    ip = camera_prev.undistort_points(np.asarray(kp_prev, float))
    rays = np.column_stack([(ic[:, 0] - camera_cur.cx) / camera_cur.fx, (ic[:, 1] - camera_cur.cy) / camera_cur.fy,
                            np.ones(len(ic))])
    r = rays @ R.T
    front = r[:, 2] > 1e-6
    pred = np.column_stack([camera_prev.fx * r[front, 0] / r[front, 2] + camera_prev.cx,
                            camera_prev.fy * r[front, 1] / r[front, 2] + camera_prev.cy])
    return np.linalg.norm(pred - ip[front], axis=1)


def rotation_free_flow(kp_cur, kp_prev, camera_cur: Camera, camera_prev: Camera, R_prev_cur) -> float:
    """Median of :func:`rotation_free_displacements` (same arguments), pixels; 0.0 when no ray
    lies in front."""
    d = rotation_free_displacements(kp_cur, kp_prev, camera_cur, camera_prev, R_prev_cur)
    return float(np.median(d)) if len(d) else 0.0


class EpipolarGatedMatcher:
    """``matcher`` whose matches pass a fundamental-matrix RANSAC (module docstring).

    Args:
        matcher: the underlying matcher (extracts and matches).
        threshold_px: RANSAC inlier distance to the epipolar line, ideal pixels.
        min_matches: pairs with fewer matches are returned ungated (too few for RANSAC).

    Attributes:
        camera: the camera of the frames being matched (set by the caller; None: raw pixels).
    """

    def __init__(self, matcher: Matcher, threshold_px: float = 1.0, min_matches: int = 15):
        self.matcher = matcher
        self.threshold_px = float(threshold_px)
        self.min_matches = int(min_matches)
        self.camera: Camera | None = None
        self.name = f"{getattr(matcher, 'name', 'matcher')}+epipolar"

    def extract(self, image) -> Features:
        return self.matcher.extract(image)

    def match(self, a: Features, b: Features) -> Matches:
        """Matches of ``a`` with ``b`` that pass the gate."""
        m = self.matcher.match(a, b)
        if len(m) < self.min_matches:
            return m
        pa = np.asarray(a.keypoints[m.idx_a], np.float64)
        pb = np.asarray(b.keypoints[m.idx_b], np.float64)
        if self.camera is not None and self.camera.is_distorted:
            pa, pb = self.camera.undistort_points(pa), self.camera.undistort_points(pb)
        cv2.setRNGSeed(0)  # RANSAC draws from OpenCV's global generator: the same result on every call
        F, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, self.threshold_px, 0.999)
        if F is None or mask is None or F.shape != (3, 3):
            return m
        keep = mask.ravel().astype(bool)
        return Matches(m.idx_a[keep], m.idx_b[keep], m.confidence[keep])
