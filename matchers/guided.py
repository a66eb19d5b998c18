"""Pose-guided matching: nearest neighbours only inside each keypoint's epipolar band.

When the relative pose of two images is known before matching (ground truth, IMU
preintegration, the odometry), the match of a keypoint of image ``a`` lies on its epipolar
line in image ``b``, up to the keypoint noise and the error of the pose. Guided matching
compares each keypoint only with the keypoints of ``b`` inside that band and takes the
nearest neighbour there (Lowe's ratio test and the mutual check among in-band candidates,
as :func:`matchers.sift.ratio_match` does over the whole image). A repeated texture
elsewhere in the image can then neither be matched nor spoil the ratio test of a good match.

The band of the pair ``(i, j)`` (keypoint ``i`` of ``a``, ``j`` of ``b``)::

    |d_ij| <= floor_px + sigmas * sigma_ij

``d_ij``: the distance (ideal pixels of ``b``) of keypoint ``j`` from the epipolar line of
``i``; ``sigma_ij``: the 1-sigma displacement of that line at keypoint ``j`` caused by the
pose error, first order: with ``T_b_a = (R, t)`` and the right perturbation
``T_b_a Exp(xi)``, ``xi = (rotation rad, translation m)`` in camera ``a``'s frame (the
convention of :attr:`vio_depth.poses.RelativePose.covariance`, gtsam's ``Pose3``), the
normalised epipolar line ``l_i = t x R x_i`` moves by ``A_i xi`` with
``A_i = [-[t]x R [x_i]x, -[R x_i]x R]``; so ``Cov(l_i) = A_i Sigma A_i^T`` and
``sigma_ij^2 = x_j^T Cov(l_i) x_j`` (in pixel coordinates, divided by the squared norm of the
line's normal). The band therefore widens along the line away from where the pose error
pivots it; without a covariance (an exact pose) it is ``floor_px`` wide.

All epipolar lines in ``b`` pass through the epipole, so the band is found without testing
every pair: ``b``'s keypoints are binned in rings around the epipole and sorted by angle,
``a``'s by the angle of their line; a block of neighbouring lines then has all its
candidates in each ring in one angular window (found by binary search; lines whose window
covers a quarter of the ring form blocks of their own), compared in one small matrix
product and tested exactly against the band. Each block's similarities are reduced where
they are computed to the best and second best per keypoint of ``a`` and of ``b``
(:func:`band_two_best`); the pairs are never listed. The products run on one BLAS thread
(small products only wait on each other's threads). No Python loop runs per keypoint (only
per ring and block of lines). The similarities are float32 dot products, so a near-tie may
resolve differently from :func:`matchers.sift.ratio_match`'s exact re-ranking.

A pose without translation has no epipolar geometry (every line degenerates): such pairs are
matched exhaustively (:func:`matchers.sift.ratio_match`), as are keypoints whose line is
undefined (a keypoint at the epipole of ``a``: all of ``b`` is its band).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from threadpoolctl import threadpool_limits

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import skew, skews

from .base import Features, Matcher, Matches

#: the similarity a missing second in-band candidate counts as: an orthogonal descriptor,
#: distance sqrt(2), the farthest two non-negative unit descriptors (SIFT, RootSIFT) can be
ABSENT_SECOND_SIMILARITY = 0.0


@dataclass(frozen=True)
class GuidedSettings:
    """Pose-guided matching (:mod:`matchers.guided`), an option of nearest-neighbour matchers.

    Attributes:
        enabled: match inside the epipolar band where the relative pose is known (default
            off: exhaustive matching, as before).
        floor_px: half-width of the band for an exact pose, ideal pixels: the keypoints'
            noise and what the triangulation's Sampson test (1.5 px) still accepts.
        sigmas: the band widens by this many 1-sigma displacements of the epipolar line
            caused by the stated pose covariance.
        block_rows: keypoints of ``a`` (sorted by the direction of their epipolar line) whose
            candidates are compared in one matrix product per ring around the epipole; small
            blocks waste fewer products on pairs outside the band, large ones cost fewer calls.
    """

    enabled: bool = False
    floor_px: float = 3.0
    sigmas: float = 3.0
    block_rows: int = 256

    def __post_init__(self):
        if not isinstance(self.enabled, bool):
            raise SettingsError(f"guided.enabled must be true or false, got {self.enabled!r}")
        if not (math.isfinite(self.floor_px) and self.floor_px > 0):
            raise SettingsError(f"guided.floor_px must be finite and > 0, got {self.floor_px!r}")
        if not (math.isfinite(self.sigmas) and self.sigmas >= 0):
            raise SettingsError(f"guided.sigmas must be finite and >= 0, got {self.sigmas!r}")
        if isinstance(self.block_rows, bool) or not isinstance(self.block_rows, int) or self.block_rows < 1:
            raise SettingsError(f"guided.block_rows must be an integer >= 1, got {self.block_rows!r}")


@dataclass(frozen=True)
class EpipolarPrior:
    """What is known, before matching, of the pose of image ``a``'s camera in image ``b``'s.

    Attributes:
        camera_a, camera_b: the cameras of the two images (keypoints are raw pixels;
            they are undistorted before the epipolar geometry is applied).
        T_b_a: (4, 4) camera-a-to-camera-b transform, metres.
        covariance: (6, 6) covariance of its right-perturbation error (rotation rad, then
            translation m; module docstring), or None for an exact pose.
    """

    camera_a: Camera
    camera_b: Camera
    T_b_a: np.ndarray
    covariance: np.ndarray | None = None

    def __post_init__(self):
        check_transform("T_b_a", self.T_b_a)
        if self.covariance is not None:
            check_array("covariance", self.covariance, (6, 6), finite=True)

    @property
    def has_baseline(self) -> bool:
        """False for a pose without translation (no epipolar geometry)."""
        return bool(np.linalg.norm(self.T_b_a[:3, 3]) > 1e-9)


@runtime_checkable
class PoseGuidedMatcher(Matcher, Protocol):
    """A matcher that can use a relative pose known before matching (e.g. :class:`SiftMatcher`)."""

    def match_with_pose(self, feats_a: Features, feats_b: Features, prior: EpipolarPrior) -> Matches:
        """Correspondences given ``a``'s pose in ``b`` (the same as ``match`` when the matcher's
        guided matching is off)."""


def epipolar_lines(prior: EpipolarPrior, uv_a) -> tuple[np.ndarray, np.ndarray]:
    """Each keypoint's epipolar line in image ``b`` and the covariance of that line.

    Args:
        prior: the relative pose and cameras.
        uv_a: (N, 2) ideal (undistorted) pixels in image ``a``.

    Returns:
        ``(lines, cov)``: ``lines (N, 3)`` the lines ``l . (u, v, 1) = 0`` in ideal pixels of
        ``b``, scaled so that ``l . (u, v, 1)`` is the signed distance in pixels (rows whose
        line is undefined are zero); ``cov (N, 3, 3)`` the covariance of each scaled line
        from the pose covariance (zeros without one).
    """
    uv_a = check_array("uv_a", uv_a, (None, 2))
    R, t = prior.T_b_a[:3, :3], prior.T_b_a[:3, 3]
    Ka_inv, Kb_inv = np.linalg.inv(prior.camera_a.K), np.linalg.inv(prior.camera_b.K)
    x = np.column_stack([uv_a, np.ones(len(uv_a))]) @ Ka_inv.T  # (N, 3) normalised rays of a
    u = x @ R.T
    lines_n = np.cross(t, u)  # t x R x: the line in normalised coordinates of b
    lines = lines_n @ Kb_inv  # K_b^-T l, as rows
    norm = np.linalg.norm(lines[:, :2], axis=1)
    defined = norm > 1e-12 * max(1.0, float(np.abs(lines).max(initial=0.0)))
    scale = np.where(defined, 1.0 / np.where(defined, norm, 1.0), 0.0)
    cov = np.zeros((len(uv_a), 3, 3))
    if prior.covariance is not None:
        # A_i = [-[t]x R [x_i]x, -[u_i]x R] (module docstring), then to pixel lines of b
        tR = skew(t) @ R
        A = np.concatenate([-np.einsum("ij,njk->nik", tR, skews(x)), -skews(u) @ R], axis=2)  # (N, 3, 6)
        A = np.einsum("ji,njk->nik", Kb_inv, A)  # K_b^-T A
        cov = A @ prior.covariance @ A.transpose(0, 2, 1)
    return lines * scale[:, None], cov * (scale**2)[:, None, None]


def band_half_widths(prior: EpipolarPrior, uv_a, uv_b, settings: GuidedSettings) -> tuple[np.ndarray, np.ndarray]:
    """Distances to the epipolar lines and the band's half-widths for all pairs (dense; for
    tests and diagnostics: :func:`guided_ratio_match` does the same in blocks).

    Args:
        prior: the relative pose and cameras.
        uv_a: (Na, 2) ideal pixels of image ``a``. uv_b: (Nb, 2) ideal pixels of image ``b``.
        settings: the band's floor and sigma multiple.

    Returns:
        ``(distance, half_width)``, each (Na, Nb) pixels of ``b``: ``|d_ij|`` and
        ``floor_px + sigmas * sigma_ij`` (inf in rows whose line is undefined).
    """
    uv_b = check_array("uv_b", uv_b, (None, 2))
    lines, cov = epipolar_lines(prior, uv_a)
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    distance = np.abs(lines @ xb.T)
    sigma = np.sqrt(np.maximum(np.einsum("jk,ikl,jl->ij", xb, cov, xb), 0.0))
    half = settings.floor_px + settings.sigmas * sigma
    half[~lines.any(axis=1)] = np.inf
    return distance, half


def _quadratic_terms(xb: np.ndarray) -> np.ndarray:
    """(N, 6) monomials of ``x^T C x`` for rows ``x = (u, v, 1)``."""
    u, v = xb[:, 0], xb[:, 1]
    return np.column_stack([u * u, v * v, np.ones(len(u)), 2 * u * v, 2 * u, 2 * v])


#: keypoints of ``b`` are binned by their distance from the epipole in rings ``[R, 2 R)``
#: starting at this radius (pixels; nearer keypoints are candidates of every line)
_FIRST_RING_PX = 16.0
#: where the epipole lies beyond this many pixels (translation nearly parallel to the image
#: plane) it is placed at this distance: the lines then differ from parallel ones by less than
#: ``extent^2 / _FAR_EPIPOLE_PX`` pixels, covered by :data:`_MARGIN_PX`
_FAR_EPIPOLE_PX = 1e8
_MARGIN_PX = 1.0


def _epipole(lines, uv_b) -> np.ndarray:
    """(2,) pixels: the common point of the lines (the null vector of their scatter matrix),
    or a point :data:`_FAR_EPIPOLE_PX` away in its direction when it is farther."""
    defined = lines[np.any(lines, axis=1)]
    e_h = np.linalg.svd(defined.T @ defined)[2][-1]
    centre = 0.5 * (uv_b.min(axis=0) + uv_b.max(axis=0))
    if abs(e_h[2]) > 0 and np.linalg.norm(e_h[:2] / e_h[2] - centre) < _FAR_EPIPOLE_PX:
        return e_h[:2] / e_h[2]
    return centre + _FAR_EPIPOLE_PX * e_h[:2] / np.linalg.norm(e_h[:2])


def _rings(uv_b, e):
    """``[(radius, order)]``: ``b``'s keypoints binned by distance from the epipole ``e`` in rings
    ``[R, 2R)`` (radius 0: the keypoints nearer than :data:`_FIRST_RING_PX`), each ring's
    indices sorted by angle mod pi, with their angles."""
    v = uv_b - e
    r = np.hypot(v[:, 0], v[:, 1])
    theta = np.mod(np.arctan2(v[:, 1], v[:, 0]), np.pi)
    ring = np.floor(np.log2(np.maximum(r, _FIRST_RING_PX) / _FIRST_RING_PX)).astype(np.int64)
    ring[r < _FIRST_RING_PX] = -1
    out = []
    for k in np.unique(ring):  # a handful of rings (log2 of the image's extent)
        members = np.flatnonzero(ring == k)
        order = members[np.argsort(theta[members], kind="stable")]
        out.append((0.0 if k < 0 else _FIRST_RING_PX * 2.0**k, order, theta[order]))
    return out


def band_pairs(prior: EpipolarPrior, uv_a, uv_b, settings: GuidedSettings, desc_a, desc_b):
    """The in-band pairs and their descriptor similarities.

    Args:
        prior, settings: the band. uv_a: (Na, 2), uv_b: (Nb, 2) ideal pixels.
        desc_a: (Na, D), desc_b: (Nb, D) float32 unit descriptors.

    Returns:
        ``(rows, cols, sims)``: (P,) int64 indices into ``a`` (ascending) and ``b`` of the
        pairs inside the band, and their float32 similarities ``desc_a[i] . desc_b[j]``.

    All epipolar lines pass through the epipole ``e``: keypoint ``j`` at angle ``theta_j`` and
    distance ``r_j`` from ``e`` is ``r_j |sin(theta_j - phi_i)|`` from the line of direction
    ``phi_i``. ``b``'s keypoints are binned in rings ``r in [R, 2R)`` around ``e`` and sorted by
    angle; ``a``'s keypoints are sorted by ``phi``. A block of ``block_rows`` consecutive
    lines then has its candidates in each ring in one contiguous angular window (those within
    ``asin(bound / R)`` of some line of the block: a superset of the band): one small matrix
    product per block and ring gives their similarities, and the exact band test keeps the
    pairs inside.
    """
    rows, cols, sims = [], [], []
    for r_idx, c_idx, inside, s in _band_blocks(prior, uv_a, uv_b, settings, desc_a, desc_b):
        r, c = np.nonzero(inside)
        rows.append(r_idx[r])
        cols.append(c_idx[c])
        sims.append(s[r, c])
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    rows, cols, sims = np.concatenate(rows), np.concatenate(cols), np.concatenate(sims)
    order = _stable_order(rows, len(uv_a))
    return rows[order], cols[order], sims[order].astype(np.float32, copy=False)


def _band_blocks(prior: EpipolarPrior, uv_a, uv_b, settings: GuidedSettings, desc_a, desc_b):
    """Yields ``(rows (m,), cols (w,), inside (m, w) bool, sims (m, w) float32)`` per block of
    lines and ring: every in-band pair appears in exactly one block (:func:`band_pairs`)."""
    lines, cov = epipolar_lines(prior, uv_a)
    undefined = ~lines.any(axis=1)
    k2 = settings.sigmas**2
    # x^T C x as (N, 6) . (M, 6): the six distinct entries of each line covariance, times sigmas^2
    c6 = k2 * np.column_stack([cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2], cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]])
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    q = _quadratic_terms(xb)
    e = _epipole(lines, uv_b) if not undefined.all() else np.zeros(2)
    # each line's angle as seen from the epipole: towards its point nearest to the image centre
    # (for a finite epipole the line's own direction; for a far one the direction from the
    # epipole placed far away, which differs from the parallel line by < _MARGIN_PX in the image)
    centre = 0.5 * (uv_b.min(axis=0) + uv_b.max(axis=0))
    foot = centre - (lines[:, :2] @ centre + lines[:, 2])[:, None] * lines[:, :2]
    v = foot - e
    at_e = np.hypot(v[:, 0], v[:, 1]) < 1e-6
    v[at_e] = np.column_stack([lines[at_e, 1], -lines[at_e, 0]])  # direction (b, -a) of a x + b y + c = 0
    phi = np.mod(np.arctan2(v[:, 1], v[:, 0]), np.pi)
    by_phi = np.argsort(phi, kind="stable")
    a_sorted = desc_a[by_phi]
    c6_sorted = c6[by_phi]
    l32, c32 = lines[by_phi].astype(np.float32), c6_sorted.astype(np.float32)
    floor = np.float32(settings.floor_px)
    for radius, order, t in _rings(uv_b, e):
        n = len(order)
        pool = np.concatenate([order, order, order])  # angles t - pi, t, t + pi: windows never wrap
        t3 = np.concatenate([t - np.pi, t, t + np.pi])
        b3 = desc_b[pool]
        x3 = np.ascontiguousarray(xb[pool].T, np.float32)
        q3 = np.ascontiguousarray(q[pool].T, np.float32)
        # each line's widest band over the ring's keypoints: x^T C x is convex, so its largest
        # value over their bounding box is at a corner
        lo, hi = uv_b[order].min(axis=0), uv_b[order].max(axis=0)
        corners = np.array([[lo[0], lo[1], 1.0], [lo[0], hi[1], 1.0], [hi[0], lo[1], 1.0], [hi[0], hi[1], 1.0]])
        b_bound = settings.floor_px + _MARGIN_PX + np.sqrt(np.maximum(c6_sorted @ _quadratic_terms(corners).T,
                                                                      0.0).max(axis=1))
        b_bound[undefined[by_phi]] = np.inf
        b_phi = phi[by_phi]
        half = np.arcsin(np.minimum(b_bound / radius, 1.0)) if radius > 0 else np.full(len(phi), np.pi)
        lo_i = np.searchsorted(t3, b_phi - half, side="left")
        hi_i = np.searchsorted(t3, b_phi + half, side="right")
        # lines whose window covers a quarter of the ring compare with all of it, in blocks
        # of their own: one wide line would otherwise widen its neighbours' block
        wide = hi_i - lo_i >= max(n // 4, 1)
        for group in (np.flatnonzero(~wide), np.flatnonzero(wide)):
            for start in range(0, len(group), settings.block_rows):
                blk = group[start:start + settings.block_rows]
                w0, w1 = int(lo_i[blk].min()), int(hi_i[blk].max())
                if w1 - w0 >= n:
                    w0, w1 = n, 2 * n  # the whole ring, each keypoint once
                if w1 <= w0:
                    continue
                d = np.abs(l32[blk] @ x3[:, w0:w1])
                d -= floor  # |d| <= floor + k sigma  <=>  max(|d| - floor, 0)^2 <= k^2 sigma^2
                np.maximum(d, 0, out=d)
                d *= d
                inside = d <= c32[blk] @ q3[:, w0:w1]
                inside[undefined[by_phi[blk]]] = True
                if inside.any():
                    yield by_phi[blk], pool[w0:w1], inside, a_sorted[blk] @ b3[w0:w1].T


class _TwoBest:
    """Running best and second-best similarity of each of ``n`` keypoints, merged block by
    block (each keypoint's candidates in one block are distinct from those in the others)."""

    def __init__(self, n: int):
        self.index = np.full(n, -1, np.int64)
        self.best = np.full(n, -np.inf, np.float32)
        self.second = np.full(n, -np.inf, np.float32)

    def merge(self, at, index, best, second) -> None:
        """Merge one block's ``(index, best, second)`` of the keypoints ``at`` (distinct)."""
        old_i, old_b, old_s = self.index[at], self.best[at], self.second[at]
        better = (best > old_b) | ((best == old_b) & (index < old_i) & np.isfinite(best))
        self.second[at] = np.where(better, np.maximum(old_b, second), np.maximum(old_s, best))
        self.best[at] = np.where(better, best, old_b)
        self.index[at] = np.where(better, index, old_i)


def _two_best_of(s: np.ndarray, axis: int):
    """``(argmax, best, second)`` along ``axis`` of ``s`` (left as it was)."""
    idx = np.argmax(s, axis=axis)
    other = np.arange(s.shape[1 - axis])
    at = (other, idx) if axis == 1 else (idx, other)
    best = s[at]
    s[at] = -np.inf
    second = s.max(axis=axis)
    s[at] = best
    return idx, best, second


def band_two_best(prior: EpipolarPrior, uv_a, uv_b, settings: GuidedSettings, desc_a, desc_b):
    """For each keypoint of ``a`` its most similar in-band keypoint of ``b`` and the best and
    second-best similarities, and the same for each keypoint of ``b`` (arguments as
    :func:`band_pairs`). The pairs are never listed: each block's similarities are reduced
    where they are computed.

    Returns:
        ``(nn_ab (Na,), s_ab (Na, 2), nn_ba (Nb,), s_ba (Nb, 2))``: int64 indices (-1: no
        in-band candidate) and float32 similarities (-inf where absent). Ties: the lower index.
    """
    ab, ba = _TwoBest(len(uv_a)), _TwoBest(len(uv_b))
    for rows, cols, inside, s in _band_blocks(prior, uv_a, uv_b, settings, desc_a, desc_b):
        s[~inside] = -np.inf
        if s.shape[1] > 1:
            j, best, second = _two_best_of(s, 1)
        else:
            j, best, second = np.zeros(len(s), np.int64), s[:, 0], np.full(len(s), -np.inf, np.float32)
        ab.merge(rows, cols[j], best, second)
        if s.shape[0] > 1:
            i, best, second = _two_best_of(s, 0)
        else:
            i, best, second = np.zeros(s.shape[1], np.int64), s[0], np.full(s.shape[1], -np.inf, np.float32)
        ba.merge(cols, rows[i], best, second)
    return ab.index, np.column_stack([ab.best, ab.second]), ba.index, np.column_stack([ba.best, ba.second])


def _stable_order(keys, n: int) -> np.ndarray:
    """``argsort(keys, kind="stable")`` of integer keys in ``[0, n)``; as int16 where they fit,
    which numpy sorts by radix in linear time (a tenth of a comparison sort of 2 million keys)."""
    return np.argsort(keys.astype(np.int16) if n <= np.iinfo(np.int16).max else keys, kind="stable")


def _distances(s: np.ndarray) -> np.ndarray:
    """Euclidean distances of unit descriptors from similarities; an absent one (-inf) counts
    as :data:`ABSENT_SECOND_SIMILARITY`."""
    s = np.where(np.isfinite(s), s, np.float32(ABSENT_SECOND_SIMILARITY))
    return np.sqrt(np.maximum(2.0 - 2.0 * s, 0.0))


def guided_ratio_match(desc_a, desc_b, uv_a, uv_b, prior: EpipolarPrior, settings: GuidedSettings,
                       ratio: float = 0.8, mutual: bool = True) -> Matches:
    """Lowe ratio test (and the mutual check) among the in-band candidates of each keypoint.

    Args:
        desc_a: (Na, D) float32 unit-L2 descriptors of image ``a``; desc_b: (Nb, D) of ``b``.
        uv_a: (Na, 2) ideal (undistorted) pixels of ``a``'s keypoints; uv_b: (Nb, 2) of ``b``'s.
        prior: the relative pose of ``a`` in ``b``, its covariance and the cameras.
        settings: the band (:class:`GuidedSettings`; ``enabled`` is not consulted here).
        ratio: Lowe's threshold on ``d1 / d2`` (Euclidean), in (0, 1].
        mutual: also require ``b``'s nearest in-band neighbour to be ``a`` (and its ratio test).

    Returns:
        :class:`Matches` (ascending ``idx_a``) with confidence ``clip(1 - r / ratio, 0, 1)``
        as :func:`matchers.sift.ratio_match`. A keypoint with a single in-band candidate
        compares it with an orthogonal descriptor (:data:`ABSENT_SECOND_SIMILARITY`).
        Fewer than 2 descriptors on either side: empty matches.
    """
    if not 0.0 < ratio <= 1.0:
        raise InputError(f"ratio must be in (0, 1], got {ratio}")
    a = np.ascontiguousarray(check_array("desc_a", desc_a, (None, None), dtype=np.float32))
    b = np.ascontiguousarray(check_array("desc_b", desc_b, (None, a.shape[1]), dtype=np.float32))
    uv_a = check_array("uv_a", uv_a, (len(a), 2), finite=True)
    uv_b = check_array("uv_b", uv_b, (len(b), 2), finite=True)
    if len(a) < 2 or len(b) < 2:
        return Matches.empty()
    with threadpool_limits(1, user_api="blas"):  # many small products: threads only wait on each other
        nn_ab, s_ab, nn_ba, s_ba = band_two_best(prior, uv_a, uv_b, settings, a, b)
    ia = np.flatnonzero(nn_ab >= 0)
    d1, d2 = _distances(s_ab[ia, 0]), _distances(s_ab[ia, 1])
    tiny = np.float32(1e-12)
    passed = d1 < ratio * d2
    ia, nn = ia[passed], nn_ab[ia[passed]]
    r = d1[passed] / np.maximum(d2[passed], tiny)
    if mutual:
        e1, e2 = _distances(s_ba[nn, 0]), _distances(s_ba[nn, 1])
        keep = (nn_ba[nn] == ia) & (e1 < ratio * e2)
        ia, nn, r = ia[keep], nn[keep], np.maximum(r, e1 / np.maximum(e2, tiny))[keep]
    conf = np.clip(1.0 - r / ratio, 0.0, 1.0).astype(np.float32)
    return Matches(ia.astype(np.int64), nn.astype(np.int64), conf)
