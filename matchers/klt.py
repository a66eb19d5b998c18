"""KLT tracking front end: corners followed frame to frame by pyramidal optical flow.

This is how the visual-inertial systems robots run keep up with a 20 Hz camera on one core
(VINS-Mono's ``feature_tracker``, OpenVINS' ``TrackKLT``): instead of extracting and
matching thousands of descriptors per frame, the corners of the previous image are
followed into the next one with ``cv2.calcOpticalFlowPyrLK`` and new corners
(``cv2.goodFeaturesToTrack``) are found only where tracks are missing. A corner keeps its
*track id* for as long as it is followed, so two frames' features correspond where their
ids are equal: :meth:`KltTracker.match` is a join on ids, and nothing is ever extracted or
matched twice.

Per frame (:meth:`KltTracker.track`):

1. **Prediction.** With a :class:`MotionHint` (the camera's rotation since the previous
   frame, e.g. integrated from the gyroscope), each corner's start position is its
   previous position rotated by the infinite homography ``K R K^-1`` (through the
   camera's distortion): fast turns then stay inside the flow's search range.
2. **Flow** forward, then **backward** from the new positions: a corner whose backward flow
   does not come home within ``back_check_px`` is dropped (the forward-backward check of
   VINS-Mono's ``FLOW_BACK``), as is one that leaves the image.
3. **Outliers.** With a known rotation, the relative translation ``t`` is the only unknown
   of the epipolar constraint: a correspondence's rotated ray ``a = R f_prev`` and its ray
   ``f_cur`` satisfy ``t . (a x f_cur) = 0``. A vectorised two-point RANSAC picks the
   translation direction most correspondences agree with and drops those farther than
   ``ransac_px`` from their epipolar line (a corner that did not move once the rotation is
   removed agrees with every direction). Without a rotation: a fundamental-matrix RANSAC,
   as VINS-Mono does.
4. **Spacing and top-up.** Tracks are thinned to one per ``min_distance_px`` cell, the
   oldest kept (long tracks constrain most); new corners are detected only in the cells
   away from the kept tracks, up to ``max_tracks``.

The tracker is stateful: frames must come in order (it is not ``concurrent_extract``).
Features carry no descriptors (``(N, 0)``); their ``scores`` are the track lengths in
frames and their ``payload`` the :class:`TrackIds`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image
from vio_core.errors import SettingsError, ShapeError
from vio_core.settings import require_positive

from .base import Features, Matches, MotionHint


@dataclass(frozen=True)
class KltSettings:
    """Settings of :class:`KltTracker`.

    The defaults keep more and smaller-windowed tracks than VINS-Mono's (150 corners 30 px
    apart, 21x21): the points stage fits the depth map to them, and on the rendered street
    and room and the real KITTI-tiny slice 500 corners 12 px apart tracked with an 11x11
    window gave the lowest AbsRel (docs/benchmarks.md, "KLT front end").

    Attributes:
        max_tracks: corners kept per frame (VINS-Mono 150, OpenVINS 200-400); top-up adds new
            corners while fewer survive.
        top_up_below: new corners are searched for only when fewer than this fraction of
            ``max_tracks`` tracks survive (1: at every frame that lost one). The corner search
            (``goodFeaturesToTrack`` over the whole image) is the tracker's largest cost: 10 ms
            of a 752x564 frame on the 2-core machine, against 4 ms for one flow. At 0.9 the
            generated 752x564 ASL loop is searched at 67 of 200 frames (tracking 19.8 -> 10.8
            ms a frame, 478 tracks on average instead of 499) and its ``--poses vio`` ATE went
            from 4.1 to 3.4 mm; the 640x256 street never holds 450 corners, so nothing changes
            there (docs/benchmarks.md, "KLT: fewer corner searches").
        min_distance_px: the spacing of corners: at most one track per cell of this size, and
            new corners at least this far from each other and about this far from tracks.
        quality: ``goodFeaturesToTrack``'s quality level (fraction of the strongest corner).
        block_size: ``goodFeaturesToTrack``'s neighbourhood, pixels.
        window_px: the flow's search window (odd), pixels.
        pyramid_levels: pyramid levels above the full image (each halves it).
        max_iterations: Lucas-Kanade iterations per level.
        back_check_px: forward-backward distance beyond which a track is dropped; 0 disables
            the backward flow.
        ransac_px: epipolar distance beyond which a correspondence is an outlier, pixels.
        ransac_hypotheses: translation directions tried by the two-point RANSAC.
        border_px: a corner closer than this to the image border is dropped.
        seed: the RANSAC's random seed (results are reproducible).
    """

    max_tracks: int = 500
    top_up_below: float = 0.9
    min_distance_px: float = 12.0
    quality: float = 0.01
    block_size: int = 3
    window_px: int = 11
    pyramid_levels: int = 3
    max_iterations: int = 30
    back_check_px: float = 0.5
    ransac_px: float = 1.0
    ransac_hypotheses: int = 64
    border_px: float = 2.0
    seed: int = 0

    def __post_init__(self):
        for name in ("max_tracks", "block_size", "window_px", "max_iterations", "ransac_hypotheses"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise SettingsError(f"klt.{name} must be a positive integer, got {v!r}")
        if self.window_px % 2 == 0 or self.window_px < 3:
            raise SettingsError(f"klt.window_px must be odd and >= 3, got {self.window_px}")
        if isinstance(self.pyramid_levels, bool) or not isinstance(self.pyramid_levels, int) \
                or self.pyramid_levels < 0:
            raise SettingsError(f"klt.pyramid_levels must be an integer >= 0, got {self.pyramid_levels!r}")
        if not (isinstance(self.top_up_below, (int, float)) and 0 < self.top_up_below <= 1):
            raise SettingsError(f"klt.top_up_below must be in (0, 1], got {self.top_up_below!r}")
        if not 0 < self.quality < 1:
            raise SettingsError(f"klt.quality must be in (0, 1), got {self.quality}")
        require_positive(self, "min_distance_px", "ransac_px")
        for name in ("back_check_px", "border_px"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise SettingsError(f"klt.{name} must be finite and >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class TrackIds:
    """The track id of each keypoint of a :class:`KltTracker`'s features (``Features.payload``).

    Attributes:
        ids: (N,) int64, unique within a frame; equal ids in two frames are the same corner.
    """

    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class TrackStats:
    """What one :meth:`KltTracker.track` call did (counts of corners).

    Attributes:
        previous: tracks of the previous frame. lost_flow: lost by the flow or the image
        border. lost_back: dropped by the forward-backward check. lost_epipolar: dropped as
        epipolar outliers. thinned: dropped for spacing. new: new corners. tracks: corners
        returned.
    """

    previous: int = 0
    lost_flow: int = 0
    lost_back: int = 0
    lost_epipolar: int = 0
    thinned: int = 0
    new: int = 0
    tracks: int = 0


def _rays(camera: Camera | None, uv: np.ndarray) -> np.ndarray:
    """(N, 3) rays with z = 1 of raw pixels ``uv: (N, 2)`` (pixels themselves without a camera)."""
    if camera is None:
        return np.column_stack([uv, np.ones(len(uv))])
    return camera.backproject(camera.undistort_points(uv), np.ones(len(uv)))


def predict_rotated(uv_prev, camera: Camera, R_cur_prev) -> np.ndarray:
    """Where corners land after a pure rotation of the camera.

    Args:
        uv_prev: (N, 2) raw pixels in the previous image.
        camera: the camera of both images.
        R_cur_prev: (3, 3) rotation of the previous camera into the current one.

    Returns:
        (N, 2) raw pixels in the current image (a ray turned behind the camera keeps its
        previous position).
    """
    uv_prev = check_array("uv_prev", uv_prev, (None, 2))
    R = check_array("R_cur_prev", R_cur_prev, (3, 3), finite=True)
    if len(uv_prev) == 0:
        return np.zeros((0, 2))
    r = _rays(camera, np.asarray(uv_prev, np.float64)) @ R.T
    front = r[:, 2] > 1e-6
    out = np.asarray(uv_prev, np.float64).copy()
    out[front] = camera.distort_points(camera.project(r[front])[0])  # identity without distortion
    return out


def rotation_epipolar_inliers(rays_prev, rays_cur, R_cur_prev, threshold: float, hypotheses: int = 64,
                              seed: int = 0) -> np.ndarray:
    """Correspondences consistent with one translation direction, the rotation being known.

    Two-point RANSAC (module docstring, step 3), vectorised over hypotheses and points.

    Args:
        rays_prev: (N, 3) rays (z = 1, normalised image coordinates) in the previous camera.
        rays_cur: (N, 3) rays of the same corners in the current camera.
        R_cur_prev: (3, 3) rotation of the previous camera into the current one.
        threshold: inlier distance to the epipolar line, normalised units (pixels / focal).
        hypotheses: translation directions tried.
        seed: random seed of the pair sampling.

    Returns:
        (N,) bool inliers. Corners that did not move once the rotation is removed are
        inliers of every direction; with fewer than 5 moving corners all are kept.
    """
    a = check_array("rays_prev", rays_prev, (None, 3)) @ check_array("R_cur_prev", R_cur_prev, (3, 3)).T
    f = check_array("rays_cur", rays_cur, (len(a), 3))
    n = len(a)
    if n == 0:
        return np.zeros(0, bool)
    proj = a[:, :2] / np.where(np.abs(a[:, 2:]) > 1e-9, a[:, 2:], 1e-9)
    moving = np.flatnonzero(np.linalg.norm(proj - f[:, :2] / f[:, 2:], axis=1) > threshold)
    if len(moving) < 5:
        return np.ones(n, bool)
    normals = np.cross(a, f)  # t . normal = 0 for the true translation t
    rng = np.random.default_rng(seed)
    pairs = rng.integers(0, len(moving), size=(hypotheses, 2))
    t = np.cross(normals[moving[pairs[:, 0]]], normals[moving[pairs[:, 1]]])
    norm = np.linalg.norm(t, axis=1)
    t = t[norm > 1e-12] / norm[norm > 1e-12, None]
    if len(t) == 0:
        return np.ones(n, bool)
    # distance of f (z = 1) to each epipolar line l = t x a, |l . f| / |l[:2]|, with l . f = t . (a x f),
    # l_x = t . (a x e_x), l_y = t . (a x e_y): three (N, 3) @ (3, H) products instead of the (H, N, 3)
    # lines (0.9 instead of 3.5 ms for 500 corners and 64 hypotheses; the same inliers)
    zero = np.zeros(n)
    num = np.abs(np.cross(a, f / f[:, 2:]) @ t.T)
    lx = np.column_stack([zero, a[:, 2], -a[:, 1]]) @ t.T
    ly = np.column_stack([-a[:, 2], zero, a[:, 0]]) @ t.T
    inliers = num <= threshold * np.maximum(np.sqrt(lx * lx + ly * ly), 1e-12)  # (N, H)
    return inliers[:, int(np.argmax(inliers.sum(axis=0)))]


def spaced_oldest(uv, age, cell_px: float, width: int, height: int) -> np.ndarray:
    """Indices of the tracks kept when at most one may occupy each ``cell_px`` cell: the oldest.

    Args:
        uv: (N, 2) pixels. age: (N,) track lengths (ties: the lower index).
        cell_px: cell size, pixels. width, height: the image size, pixels.

    Returns:
        (K,) sorted indices into ``uv``.
    """
    uv = check_array("uv", uv, (None, 2))
    age = check_array("age", age, (len(uv),), dtype=None)
    if len(uv) == 0:
        return np.zeros(0, np.int64)
    cols = int(np.ceil(width / cell_px)) + 1
    cell = (np.floor(uv[:, 1] / cell_px) * cols + np.floor(uv[:, 0] / cell_px)).astype(np.int64)
    order = np.lexsort((np.arange(len(uv)), -np.asarray(age), cell))
    _, first = np.unique(cell[order], return_index=True)
    return np.sort(order[first])


def free_mask(uv, radius_px: float, width: int, height: int) -> np.ndarray:
    """(H, W) uint8 mask, 255 where a new corner may be detected: away from the tracks ``uv: (N, 2)``.

    The image is cut into cells of half ``radius_px``; a cell within ``radius_px`` (in
    cells, a square) of a track is blocked.
    """
    uv = check_array("uv", uv, (None, 2))
    cell = max(1, int(radius_px // 2))
    gh, gw = -(-height // cell), -(-width // cell)
    occupied = np.zeros((gh, gw), np.uint8)
    if len(uv):
        c = np.clip((uv // cell).astype(np.int64), 0, [gw - 1, gh - 1])
        occupied[c[:, 1], c[:, 0]] = 1
        r = max(1, int(round(radius_px / cell)))
        occupied = cv2.dilate(occupied, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    blocked = np.repeat(np.repeat(occupied, cell, axis=0), cell, axis=1)[:height, :width]
    return np.where(blocked > 0, 0, 255).astype(np.uint8)


class KltTracker:
    """The KLT tracking front end (module docstring); a :class:`~matchers.Matcher` whose
    ``extract`` tracks (frames in order) and whose ``match`` joins track ids."""

    name = "klt"
    #: ``extract`` follows the previous frame: frames must come in order, in one thread
    concurrent_extract = False

    def __init__(self, settings: KltSettings | None = None):
        self.settings = KltSettings() if settings is None else settings
        self._next_id = 0
        #: what the last :meth:`track` did
        self.last_stats = TrackStats()
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame (the next one starts new tracks; ids keep increasing)."""
        self._grey = None
        self._uv = np.zeros((0, 2), np.float32)
        self._ids = np.zeros(0, np.int64)
        self._age = np.zeros(0, np.int64)
        self._size: tuple[int, int] | None = None

    def extract(self, image) -> Features:
        """:meth:`track` without a motion hint."""
        return self.track(image)

    def _flow(self, pyr_a, pyr_b, uv_a, uv_init):
        s = self.settings
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, s.max_iterations, 0.01)
        uv_b, status, _ = cv2.calcOpticalFlowPyrLK(
            pyr_a, pyr_b, uv_a.reshape(-1, 1, 2), uv_init.reshape(-1, 1, 2).copy(), winSize=(s.window_px, s.window_px),
            maxLevel=s.pyramid_levels, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        return uv_b.reshape(-1, 2), status.reshape(-1).astype(bool)

    def track(self, image, hint: MotionHint | None = None) -> Features:
        """The features of the next frame: the previous corners followed, new ones added.

        Args:
            image: (H, W, 3) uint8 RGB or (H, W) uint8 grey, the same size as the previous frame's.
            hint: the camera's rotation since the previous frame, or None.

        Returns:
            :class:`~matchers.Features` with ``keypoints (N, 2) float32`` raw pixels,
            ``descriptors (N, 0)``, ``scores (N,)`` track lengths in frames and ``payload`` the
            :class:`TrackIds`.

        Raises:
            ShapeError: not a uint8 image, or another size than the previous frame's.
        """
        img = np.asarray(image)
        img = check_image("image", img, channels=3) if img.ndim == 3 else check_image("image", img, channels=None)
        if img.dtype != np.uint8:
            raise ShapeError(f"image: expected uint8, got dtype {img.dtype}")
        grey = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        h, w = grey.shape
        if self._size is not None and self._size != (w, h):
            raise ShapeError(f"image: {w}x{h} after {self._size[0]}x{self._size[1]}; call reset() between cameras")
        s = self.settings
        pyramid = np.ascontiguousarray(grey)  # OpenCV's Python binding takes images, not pyramids
        prev = len(self._uv)
        uv, ids, age = self._uv, self._ids, self._age
        lost_flow = lost_back = lost_epi = 0
        if self._grey is not None and prev:
            uv, ids, age, lost_flow, lost_back, lost_epi = self._follow(pyramid, hint, w, h)
        keep = spaced_oldest(uv, age, s.min_distance_px, w, h)
        thinned = len(uv) - len(keep)
        uv, ids, age = uv[keep], ids[keep], age[keep] + 1
        n_new = 0
        if len(uv) < s.top_up_below * s.max_tracks:  # top_up_below <= 1
            corners = cv2.goodFeaturesToTrack(grey, s.max_tracks - len(uv), s.quality, s.min_distance_px,
                                              mask=free_mask(uv, s.min_distance_px, w, h), blockSize=s.block_size)
            if corners is not None:
                new = corners.reshape(-1, 2).astype(np.float32)
                b = s.border_px
                new = new[(new[:, 0] >= b) & (new[:, 0] <= w - 1 - b) & (new[:, 1] >= b) & (new[:, 1] <= h - 1 - b)]
                n_new = len(new)
                uv = np.concatenate([uv, new])
                ids = np.concatenate([ids, np.arange(self._next_id, self._next_id + n_new, dtype=np.int64)])
                age = np.concatenate([age, np.ones(n_new, np.int64)])
                self._next_id += n_new
        self._grey, self._uv, self._ids, self._age, self._size = pyramid, uv.astype(np.float32), ids, age, (w, h)
        self.last_stats = TrackStats(prev, lost_flow, lost_back, lost_epi, thinned, n_new, len(uv))
        return Features(self._uv.copy(), np.zeros((len(uv), 0), np.float32), age.astype(np.float32), (w, h),
                        payload=TrackIds(ids.copy()))

    def _follow(self, pyramid, hint: MotionHint | None, w: int, h: int):
        """The previous corners in the new image: flow, backward check, border, epipolar RANSAC."""
        s = self.settings
        uv0 = self._uv.astype(np.float32)
        init = uv0
        rotation = hint is not None and hint.R_cur_prev is not None
        if rotation:
            init = predict_rotated(uv0, hint.camera, hint.R_cur_prev).astype(np.float32)
            init = np.clip(init, 0, [w - 1, h - 1]).astype(np.float32)
        uv1, ok = self._flow(self._grey, pyramid, uv0, init)
        b = s.border_px
        ok &= np.isfinite(uv1).all(axis=1) & (uv1[:, 0] >= b) & (uv1[:, 0] <= w - 1 - b) \
            & (uv1[:, 1] >= b) & (uv1[:, 1] <= h - 1 - b)
        lost_flow = int((~ok).sum())
        lost_back = 0
        if s.back_check_px > 0 and ok.any():
            idx = np.flatnonzero(ok)
            back, ok_back = self._flow(pyramid, self._grey, uv1[idx], uv0[idx])
            good = ok_back & (np.linalg.norm(back - uv0[idx], axis=1) <= s.back_check_px)
            ok[idx[~good]] = False
            lost_back = int((~good).sum())
        idx = np.flatnonzero(ok)
        lost_epi = 0
        if len(idx) >= 8:
            camera = hint.camera if hint is not None else None
            if rotation:
                inl = rotation_epipolar_inliers(_rays(camera, uv0[idx].astype(np.float64)),
                                                _rays(camera, uv1[idx].astype(np.float64)), hint.R_cur_prev,
                                                s.ransac_px / camera.fx, s.ransac_hypotheses, s.seed)
            else:
                inl = self._fundamental_inliers(camera, uv0[idx], uv1[idx])
            ok[idx[~inl]] = False
            lost_epi = int((~inl).sum())
        return uv1[ok], self._ids[ok], self._age[ok], lost_flow, lost_back, lost_epi

    def _fundamental_inliers(self, camera: Camera | None, uv0: np.ndarray, uv1: np.ndarray) -> np.ndarray:
        """Fundamental-matrix RANSAC inliers (ideal pixels when the camera is known)."""
        a, b = uv0.astype(np.float64), uv1.astype(np.float64)
        if camera is not None and camera.is_distorted:
            a, b = camera.undistort_points(a), camera.undistort_points(b)
        _, mask = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, self.settings.ransac_px, 0.99)
        if mask is None:
            return np.ones(len(a), bool)
        return mask.reshape(-1).astype(bool)

    def match(self, feats_a: Features, feats_b: Features) -> Matches:
        """Correspondences of two frames' features: the keypoints with the same track id
        (confidence 1)."""
        ids = []
        for nm, f in (("feats_a", feats_a), ("feats_b", feats_b)):
            if not isinstance(f.payload, TrackIds) or len(f.payload) != len(f):
                raise ShapeError(f"{nm}: not the features of a KLT tracker (no track ids); "
                                 "features of another matcher cannot be joined by track")
            ids.append(f.payload.ids)
        _, ia, ib = np.intersect1d(ids[0], ids[1], assume_unique=True, return_indices=True)
        return Matches(ia.astype(np.int64), ib.astype(np.int64), np.ones(len(ia), np.float32))
