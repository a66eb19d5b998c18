"""Up-to-scale structure from motion over the first keyframes (the dynamic initialisation).

The keyframes' pairwise matches form tracks (:class:`~vio_depth.landmarks.TrackTable`).
Then, as VINS-Mono does before its visual-inertial alignment:

1. the reference pair is the first keyframe and, among those sharing at least ``min_common``
   tracks with it, the one with the most shared tracks times median image motion; its essential matrix
   (RANSAC on undistorted rays with a 2 px threshold and a fixed seed, ``cv2.findEssentialMat``
   + ``cv2.recoverPose``) gives the
   relative rotation and the direction of the translation, whose length is set to 1;
2. tracks seen by posed keyframes are triangulated
   (:func:`triangulation.multiview.triangulate_tracks`); each further keyframe, the one
   seeing most triangulated points first, is posed by PnP (``cv2.solvePnPRansac``) and
   new tracks are triangulated;
3. a bundle adjustment (gtsam, Huber kernel) refines every pose and point, the first
   pose fixed and the reference pair's distance held at 1 (the gauge of an up-to-scale
   reconstruction).

The result is the camera poses in the first camera's frame, with an unknown scale
(:class:`SfmResult`); failures are results with a reason, never exceptions.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from triangulation.multiview import MultiviewSettings, triangulate_tracks
from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.geometry import invert_transform, make_transform

from ..landmarks import FrameMatches, TrackTable

#: triangulation settings of an up-to-scale reconstruction (depths in units of the reference baseline)
_SFM_TRIANGULATION = MultiviewSettings(pixel_sigma_px=1.0, max_residual_sigmas=3.0, max_relative_sigma=0.25,
                                       min_depth_m=1e-3, max_depth_m=1e4)


@dataclass(frozen=True)
class SfmKeyframe:
    """One keyframe of the reconstruction.

    Attributes:
        frame_id: increasing frame id.
        camera: its camera.
        keypoints: (N, 2) raw pixels.
        matches: :class:`~vio_depth.landmarks.FrameMatches` with earlier keyframes of the list.
    """

    frame_id: int
    camera: Camera
    keypoints: np.ndarray
    matches: tuple[FrameMatches, ...] = ()

    def __post_init__(self):
        check_array("keypoints", self.keypoints, (None, 2))


@dataclass(frozen=True)
class SfmResult:
    """An up-to-scale reconstruction of the keyframes, or why there is none.

    Attributes:
        ok: True when every keyframe was posed and the checks passed.
        reason: why not ("" when ok).
        T_c0_c: (K, 4, 4) camera-to-first-camera poses; translations in units of the
            reference pair's baseline (unknown metric scale).
        landmarks: points of the final reconstruction.
        median_residual_px: median reprojection residual of their observations, ideal pixels.
        reference: frame ids of the reference pair.
    """

    ok: bool
    reason: str = ""
    T_c0_c: np.ndarray | None = None
    landmarks: int = 0
    median_residual_px: float = float("nan")
    reference: tuple[int, int] = (-1, -1)


def _rays(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """(N, 2) normalised image coordinates (undistorted) of raw pixels ``uv: (N, 2)``."""
    ideal = camera.undistort_points(np.asarray(uv, float))
    return np.column_stack([(ideal[:, 0] - camera.cx) / camera.fx, (ideal[:, 1] - camera.cy) / camera.fy])


def _triangulate(obs, keyframes, poses: dict[int, np.ndarray]):
    """Triangulate every track with >= 2 observations in posed views: (track ids (T,), points (T, 3), valid (T,))."""
    ids = sorted(poses)
    use = np.isin(obs.frame, ids)
    if use.sum() < 2:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, bool), None
    view = np.searchsorted(ids, obs.frame[use])
    res = triangulate_tracks(obs.track[use], view, obs.uv[use], [keyframes[i].camera for i in ids],
                             np.stack([poses[i] for i in ids]), _SFM_TRIANGULATION)
    return res.track_ids, res.points_w, res.valid, res


def _essential(keyframes, obs, i: int, j: int):
    """Relative pose ``T_ci_cj`` (unit translation) of keyframes ``i`` and ``j`` from their common tracks."""
    a = obs.frame == i
    b = obs.frame == j
    common, ia, ib = np.intersect1d(obs.track[a], obs.track[b], return_indices=True)
    if len(common) < 8:
        return None, 0
    pa = _rays(keyframes[i].camera, obs.uv[a][ia])
    pb = _rays(keyframes[j].camera, obs.uv[b][ib])
    f = 0.5 * (keyframes[i].camera.fx + keyframes[i].camera.fy)
    cv2.setRNGSeed(0)  # RANSAC draws from OpenCV's global generator: the same result on every call
    E, mask = cv2.findEssentialMat(pa, pb, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=2.0 / f)
    if E is None or E.shape != (3, 3):
        return None, 0
    n, R, t, mask = cv2.recoverPose(E, pa, pb, np.eye(3), mask=mask)
    T_cj_ci = make_transform(R, t.reshape(3) / max(np.linalg.norm(t), 1e-12))
    return invert_transform(T_cj_ci), int(n)


def _pnp(keyframe: SfmKeyframe, obs, track_ids, points, valid, frame: int):
    """Pose ``T_c0_c`` of ``keyframe`` from its observations of triangulated tracks, or None."""
    sel = obs.frame == frame
    rows = np.searchsorted(track_ids, obs.track[sel]) if len(track_ids) else np.zeros(0, np.int64)
    rows = np.clip(rows, 0, max(len(track_ids) - 1, 0))
    has = (len(track_ids) > 0) & (track_ids[rows] == obs.track[sel]) & valid[rows] if len(track_ids) else rows > 0
    if has.sum() < 12:
        return None
    obj = points[rows[has]].astype(np.float64)
    img = _rays(keyframe.camera, obs.uv[sel][has]).astype(np.float64)
    f = 0.5 * (keyframe.camera.fx + keyframe.camera.fy)
    cv2.setRNGSeed(0)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, np.eye(3), None, reprojectionError=4.0 / f,
                                             iterationsCount=200, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < max(10, 0.3 * has.sum()):
        return None
    ok, rvec, tvec = cv2.solvePnP(obj[inl[:, 0]], img[inl[:, 0]], np.eye(3), None, rvec, tvec,
                                  useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    R, _ = cv2.Rodrigues(rvec)
    return invert_transform(make_transform(R, tvec.reshape(3)))


def _bundle_adjust(keyframes, obs, poses: dict[int, np.ndarray], reference: tuple[int, int], iterations: int = 30):
    """Refine poses and points (gtsam LM, Huber); the first pose fixed, the reference distance 1."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    track_ids, points, valid, res = _triangulate(obs, keyframes, poses)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    first = min(poses)
    graph.add(gtsam.PriorFactorPose3(X(first), gtsam.Pose3(poses[first]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    graph.add(gtsam.RangeFactorPose3(X(reference[0]), X(reference[1]), 1.0, gtsam.noiseModel.Isotropic.Sigma(1, 1e-4)))
    for f, T in poses.items():
        values.insert(X(f), gtsam.Pose3(T))
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.5),
                                            gtsam.noiseModel.Isotropic.Sigma(2, 1.0))
    cals = {f: gtsam.Cal3_S2(k.camera.fx, k.camera.fy, 0.0, k.camera.cx, k.camera.cy) for f, k in keyframes.items()}
    if res is None:
        return poses
    use = np.isin(obs.frame, sorted(poses))
    frames, tracks, uv = obs.frame[use], obs.track[use], obs.uv[use]
    keep = res.inlier & valid[res.obs_track]
    for r in np.nonzero(valid & np.isin(track_ids, tracks[keep]))[0]:
        values.insert(L(int(track_ids[r])), gtsam.Point3(*points[r]))
    for f in np.unique(frames[keep]):
        sel = keep & (frames == f)
        ideal = keyframes[int(f)].camera.undistort_points(uv[sel])
        for tid, xy in zip(tracks[sel], ideal):
            graph.add(gtsam.GenericProjectionFactorCal3_S2(np.asarray(xy, float), robust, X(int(f)), L(int(tid)),
                                                           cals[int(f)]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError:
        return poses
    return {f: result.atPose3(X(f)).matrix() for f in poses}


def reconstruct(keyframes: list[SfmKeyframe], min_common: int = 30, min_landmarks: int = 40,
                max_residual_px: float = 2.0) -> SfmResult:
    """Up-to-scale reconstruction of ``keyframes`` (see the module docstring).

    Args:
        keyframes: in time order, each with matches to earlier ones.
        min_common: fewest tracks the reference pair must share.
        min_landmarks: fewest valid points of the final reconstruction.
        max_residual_px: largest accepted median reprojection residual, ideal pixels.
    """
    if len(keyframes) < 3:
        return SfmResult(False, f"{len(keyframes)} keyframes (< 3)")
    table = TrackTable()
    for k in keyframes:
        table.add_frame(k.frame_id, k.keypoints, list(k.matches))
    obs = table.observations(min_length=2)
    by_id = {k.frame_id: k for k in keyframes}
    first = keyframes[0].frame_id
    # 1. the reference pair: among the keyframes sharing enough tracks with the first, the one
    #    with the most shared tracks times image motion (motion counted up to 40 px: beyond, more
    #    tracks matter more than more parallax)
    best, best_score = None, 0.0
    in_first = obs.frame == first
    for k in keyframes[1:]:
        sel = obs.frame == k.frame_id
        common, ia, ib = np.intersect1d(obs.track[in_first], obs.track[sel], return_indices=True)
        if len(common) < min_common:
            continue
        motion = float(np.median(np.linalg.norm(obs.uv[in_first][ia] - obs.uv[sel][ib], axis=1)))
        score = min(motion, 40.0) * len(common)
        if score > best_score:
            best, best_score = k.frame_id, score
    if best is None:
        return SfmResult(False, f"too few tracks: no keyframe shares {min_common} tracks with the first")
    T_0_j, n_inliers = _essential(by_id, obs, first, best)
    if T_0_j is None or n_inliers < min_common // 2:
        return SfmResult(False, f"too few tracks: the essential matrix of keyframes {first} and {best} has "
                                f"{n_inliers} inliers (< {min_common // 2})")
    poses = {first: np.eye(4), best: T_0_j}
    # 2. PnP for the others, most triangulated points first
    while len(poses) < len(keyframes):
        track_ids, points, valid, _ = _triangulate(obs, by_id, poses)
        if not valid.any():
            break
        counts = {}
        for k in keyframes:
            if k.frame_id in poses:
                continue
            sel = obs.frame == k.frame_id
            counts[k.frame_id] = int(np.isin(obs.track[sel], track_ids[valid]).sum())
        nxt = max(counts, key=counts.get)
        T = _pnp(by_id[nxt], obs, track_ids, points, valid, nxt)
        if T is None:
            return SfmResult(False, f"too few tracks: keyframe {nxt} could not be posed by PnP "
                                    f"({counts[nxt]} triangulated points seen)")
        poses[nxt] = T
    if len(poses) < len(keyframes):
        return SfmResult(False, "too few tracks: nothing could be triangulated from the reference pair")
    # 3. bundle adjustment, twice (outliers re-evaluated in between)
    poses = _bundle_adjust(by_id, obs, poses, (first, best))
    poses = _bundle_adjust(by_id, obs, poses, (first, best))
    track_ids, points, valid, res = _triangulate(obs, by_id, poses)
    n_valid = int(valid.sum())
    good = res.inlier & res.valid[res.obs_track]
    median = float(np.median(res.residual_px[good])) if good.any() else float("inf")
    T = np.stack([poses[k.frame_id] for k in keyframes])
    if n_valid < min_landmarks:
        return SfmResult(False, f"too few tracks: {n_valid} points reconstructed (< {min_landmarks})", T, n_valid,
                         median, (first, best))
    if not median <= max_residual_px:
        return SfmResult(False, f"reconstruction residual {median:.2f} px (> {max_residual_px} px)", T, n_valid,
                         median, (first, best))
    return SfmResult(True, "", T, n_valid, median, (first, best))
