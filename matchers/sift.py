"""OpenCV SIFT features with a vectorised ratio-test + mutual-nearest-neighbour matcher.

Descriptors are stored **RootSIFT-normalised** by default (Arandjelovic & Zisserman,
CVPR 2012): each 128-d SIFT vector is L1-normalised and square-rooted, which makes it
unit-L2 and turns the Euclidean distance into the Hellinger distance between the
gradient histograms. It is a free, well-known improvement on the raw L2 distance. With
``root_sift=False`` the raw OpenCV descriptors are only L2-normalised. Either way every
stored descriptor has unit L2 norm, so the squared distance is ``2 - 2 * a.b`` and the
matcher works with one matrix product per block of rows.

Matching (all vectorised, blocks of rows keep the distance matrix bounded in memory):

1. for every descriptor of ``a`` the two nearest descriptors of ``b`` and vice versa;
2. Lowe's ratio test ``d1 < ratio * d2`` on Euclidean distances, in both directions;
3. mutual nearest neighbour: ``a[i]``'s nearest neighbour is ``b[j]`` and ``b[j]``'s is
   ``a[i]``.

With ``mutual=False`` only the one-directional test a -> b of step 2 is applied (plain
Lowe matching: several ``a`` may then match the same ``b``).

Confidence of a match: ``clip(1 - r / ratio, 0, 1)`` where ``r = d1 / d2`` is the
distance ratio (the larger of the two directions when ``mutual``): 1 for an unambiguous
match, 0 for one that barely passed the ratio test.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import cv2
import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, SettingsError, ShapeError

from .base import Features, Matches
from .guided import EpipolarPrior, GuidedSettings, guided_ratio_match
from .nearest import NEAREST_BACKENDS, nearest_two_rows

#: descriptor dimension of SIFT
SIFT_DIM = 128


@dataclass(frozen=True)
class SiftSettings:
    """Settings of :class:`SiftMatcher`.

    Attributes:
        max_features: keep at most this many keypoints per image (strongest responses);
            4000 covers a 1242x375 KITTI image densely without slowing matching down.
        contrast_threshold: OpenCV SIFT contrast threshold (0.04 = OpenCV/Lowe default);
            lower it for low-texture scenes to get more (weaker) keypoints.
        edge_threshold: OpenCV SIFT edge-response threshold (default 10, as Lowe).
        n_octave_layers: scales per octave (default 3, as Lowe).
        sigma: Gaussian blur of the base octave (default 1.6, as Lowe).
        ratio: Lowe ratio-test threshold on ``d1 / d2`` (Euclidean distances), in (0, 1];
            0.8 is Lowe's value. ``1.0`` effectively disables the test.
        mutual: require mutual nearest neighbours and apply the ratio test in both
            directions (default on).
        root_sift: store RootSIFT descriptors (default on), else L2-normalised SIFT.
        block_rows: rows of the distance matrix computed at once (bounds memory to
            about ``block_rows * len(b) * 4`` bytes).
        nearest_backend: how nearest neighbours are found, :mod:`matchers.nearest`:
            ``"float32"`` (numpy), ``"bfloat16"`` (a torch bfloat16 screen plus exact
            re-ranking, 2.4 x faster at 4 000 descriptors where the CPU has bfloat16 units)
            or ``"auto"`` (default: bfloat16 where native and an image has >= 3 000
            descriptors, else float32). Every backend gives the same matches, bit for bit.
        guided: pose-guided matching (:class:`~matchers.guided.GuidedSettings`; off by
            default): where the caller knows the relative pose (:meth:`SiftMatcher.match_with_pose`),
            only keypoints inside each epipolar band are compared.
    """

    max_features: int = 4000
    contrast_threshold: float = 0.04
    edge_threshold: float = 10.0
    n_octave_layers: int = 3
    sigma: float = 1.6
    ratio: float = 0.8
    mutual: bool = True
    root_sift: bool = True
    block_rows: int = 2048
    nearest_backend: str = "auto"
    guided: GuidedSettings = GuidedSettings()

    def __post_init__(self):
        if self.max_features <= 0:
            raise SettingsError(f"sift: max_features must be positive, got {self.max_features}")
        if not 0.0 < self.ratio <= 1.0:
            raise SettingsError(f"sift: ratio must be in (0, 1], got {self.ratio}")
        if self.contrast_threshold < 0 or self.edge_threshold <= 0 or self.sigma <= 0:
            raise SettingsError("sift: contrast_threshold >= 0, edge_threshold > 0 and sigma > 0 are required")
        if self.n_octave_layers < 1 or self.block_rows < 1:
            raise SettingsError("sift: n_octave_layers and block_rows must be >= 1")
        if self.nearest_backend not in NEAREST_BACKENDS:
            raise SettingsError(
                f"sift: unknown nearest_backend {self.nearest_backend!r}; valid: {', '.join(NEAREST_BACKENDS)}"
            )


def normalize_descriptors(descriptors, root_sift: bool = True) -> np.ndarray:
    """Unit-L2 descriptors from raw OpenCV SIFT ``descriptors: (N, 128)`` (non-negative).

    ``root_sift``: L1-normalise then square-root (RootSIFT); else plain L2-normalise.
    Returns ``(N, 128) float32`` with unit L2 norm (an all-zero row stays zero).
    """
    d = check_array("descriptors", descriptors, (None, SIFT_DIM), dtype=np.float32)
    if root_sift:
        l1 = d.sum(axis=1, keepdims=True)
        return np.sqrt(d / np.maximum(l1, np.finfo(np.float32).tiny)).astype(np.float32)
    l2 = np.linalg.norm(d, axis=1, keepdims=True)
    return (d / np.maximum(l2, np.finfo(np.float32).tiny)).astype(np.float32)


def nearest_two(desc_a, desc_b, block_rows: int = 2048):
    """Two nearest neighbours in both directions between unit-norm descriptor sets.

    Args:
        desc_a: (Na, D) float32, unit L2 norm rows; Na >= 2.
        desc_b: (Nb, D) float32, unit L2 norm rows; Nb >= 2.
        block_rows: rows per similarity block (memory bound ``block_rows * N * 4`` bytes).

    Returns:
        ``(nn_ab, d_ab, nn_ba, d_ba)``: ``nn_ab (Na,)`` int64 index of the nearest ``b``
        of each ``a``; ``d_ab (Na, 2)`` Euclidean distances to the nearest and second
        nearest ``b``; likewise ``nn_ba (Nb,)`` and ``d_ba (Nb, 2)`` for ``b`` -> ``a``.
    """
    a = np.ascontiguousarray(check_array("desc_a", desc_a, (None, None), dtype=np.float32))
    b = np.ascontiguousarray(check_array("desc_b", desc_b, (None, a.shape[1]), dtype=np.float32))
    if len(a) < 2 or len(b) < 2:
        raise ShapeError(f"nearest_two needs at least 2 descriptors per set, got {len(a)} and {len(b)}")
    # two products (a b^T and b a^T) keep every reduction along contiguous rows, which is
    # several times faster than column-wise argmax/argpartition on one matrix
    nn_ab, s_ab = nearest_two_rows(a, b, block_rows)
    nn_ba, s_ba = nearest_two_rows(b, a, block_rows)
    d_ab = np.sqrt(np.maximum(2.0 - 2.0 * s_ab, 0.0))
    d_ba = np.sqrt(np.maximum(2.0 - 2.0 * s_ba, 0.0))
    return nn_ab, d_ab, nn_ba, d_ba


def ratio_match(
    desc_a,
    desc_b,
    ratio: float = 0.8,
    mutual: bool = True,
    block_rows: int = 2048,
    backend: str = "float32",
) -> Matches:
    """Match unit-norm descriptors ``desc_a: (Na, D)`` and ``desc_b: (Nb, D)`` (float32).

    Lowe ratio test ``d1 < ratio * d2`` a -> b, plus (``mutual``) the same test b -> a
    and the mutual-nearest-neighbour check. Fewer than 2 descriptors on either side ->
    empty matches. Confidence = ``clip(1 - r / ratio, 0, 1)`` with ``r`` the distance ratio
    (worst of both directions when ``mutual``). ``backend``: how the nearest neighbours
    are found (:mod:`matchers.nearest`; every backend gives the same matches).

    The b -> a direction is computed only for the descriptors of ``b`` that are the nearest
    neighbour of an ``a`` passing the a -> b test (typically a third of ``b``): the others
    cannot take part in a match. This gives the same matches as the full
    :func:`nearest_two` in both directions (tests/matchers/test_sift.py), for about
    two thirds of its cost. Rows whose ratio test fails even with the error bounds of the
    backend's fast product are not re-ranked exactly (``keep`` of
    :func:`matchers.nearest.nearest_two_rows`).
    """
    if not 0.0 < ratio <= 1.0:
        raise InputError(f"ratio must be in (0, 1], got {ratio}")
    if len(desc_a) < 2 or len(desc_b) < 2:
        return Matches.empty()
    a = np.ascontiguousarray(check_array("desc_a", desc_a, (None, None), dtype=np.float32))
    b = np.ascontiguousarray(check_array("desc_b", desc_b, (None, a.shape[1]), dtype=np.float32))
    ratio2 = np.float32(ratio) ** 2

    def may_pass(s1_max, s2_min):
        # d1 < ratio * d2 with d = sqrt(2 - 2 s), at the most favourable similarities
        return (1.0 - s1_max) < ratio2 * (1.0 - s2_min)

    nn_ab, s_ab = nearest_two_rows(a, b, block_rows, backend, keep=may_pass)
    d_ab = np.sqrt(np.maximum(2.0 - 2.0 * s_ab, 0.0))
    tiny = np.float32(1e-12)
    with np.errstate(invalid="ignore"):  # rows the screen skipped hold NaN: they fail the test
        passed = d_ab[:, 0] < ratio * d_ab[:, 1]
    idx_a = np.flatnonzero(passed).astype(np.int64)
    r = d_ab[idx_a, 0] / np.maximum(d_ab[idx_a, 1], tiny)
    if mutual:
        cols, inverse = np.unique(nn_ab[idx_a], return_inverse=True)  # the b that can still match
        nn_ba, s_ba = nearest_two_rows(b[cols], a, block_rows, backend, keep=may_pass)
        d_ba = np.sqrt(np.maximum(2.0 - 2.0 * s_ba, 0.0))[inverse]
        r_ba = d_ba[:, 0] / np.maximum(d_ba[:, 1], tiny)
        with np.errstate(invalid="ignore"):
            back = (nn_ba[inverse] == idx_a) & (d_ba[:, 0] < ratio * d_ba[:, 1])
        idx_a, r = idx_a[back], np.maximum(r, r_ba)[back]
    conf = np.clip(1.0 - r / ratio, 0.0, 1.0).astype(np.float32)
    return Matches(idx_a, nn_ab[idx_a].astype(np.int64), conf)


class SiftMatcher:
    """OpenCV SIFT extraction + ratio/mutual matching (see the module docstring).

    ``extract`` runs the detector once per image; ``match`` only compares stored
    descriptors and never touches the detector. ``extract`` may run in several threads at
    once (each thread has its own OpenCV detector; OpenCV releases the GIL while it works).
    """

    name = "sift"
    #: ``extract`` is safe to call from several threads at once
    concurrent_extract = True

    def __init__(self, settings: SiftSettings | None = None):
        self.settings = SiftSettings() if settings is None else settings
        self._local = threading.local()

    def _detector(self):
        sift = getattr(self._local, "sift", None)
        if sift is None:
            s = self.settings
            sift = self._local.sift = cv2.SIFT_create(
                nfeatures=s.max_features,
                nOctaveLayers=s.n_octave_layers,
                contrastThreshold=s.contrast_threshold,
                edgeThreshold=s.edge_threshold,
                sigma=s.sigma,
            )
        return sift

    def extract(self, image) -> Features:
        """SIFT features of ``image: (H, W, 3) uint8 RGB``.

        Returns :class:`Features` with ``keypoints (N, 2) float32`` raw full-resolution
        pixels, ``descriptors (N, 128) float32`` unit-L2 (RootSIFT unless disabled),
        ``scores (N,) float32`` detector responses. N may be 0 (textureless image).
        """
        img = check_image("image", image, channels=3)
        if img.dtype != np.uint8:
            raise ShapeError(f"image: expected uint8 RGB, got dtype {img.dtype}")
        gray = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
        kps, desc = self._detector().detectAndCompute(gray, None)
        h, w = gray.shape
        if desc is None or len(kps) == 0:
            return Features(np.zeros((0, 2), np.float32), np.zeros((0, SIFT_DIM), np.float32),
                            np.zeros(0, np.float32), (w, h))
        keypoints = cv2.KeyPoint_convert(kps).astype(np.float32).reshape(-1, 2)
        scores = np.fromiter((k.response for k in kps), np.float32, count=len(kps))
        return Features(keypoints, normalize_descriptors(desc, self.settings.root_sift), scores, (w, h))

    def match(self, feats_a: Features, feats_b: Features) -> Matches:
        """Matches between two :meth:`extract` results (ratio test, mutual NN)."""
        for nm, f in (("feats_a", feats_a), ("feats_b", feats_b)):
            if len(f) and f.descriptors.shape[1] != SIFT_DIM:
                raise ShapeError(f"{nm}: expected (N, {SIFT_DIM}) SIFT descriptors, got {f.descriptors.shape}")
        s = self.settings
        return ratio_match(feats_a.descriptors, feats_b.descriptors, s.ratio, s.mutual, s.block_rows,
                           s.nearest_backend)

    def match_with_pose(self, feats_a: Features, feats_b: Features, prior: EpipolarPrior) -> Matches:
        """Matches when the relative pose is known (``prior``: ``a``'s camera in ``b``'s).

        With ``settings.guided.enabled`` and a pose with a baseline: the ratio test and the
        mutual check among the keypoints inside each epipolar band (:mod:`matchers.guided`);
        otherwise exactly :meth:`match`.
        """
        g = self.settings.guided
        if not g.enabled or not prior.has_baseline:
            return self.match(feats_a, feats_b)
        for nm, f in (("feats_a", feats_a), ("feats_b", feats_b)):
            if len(f) and f.descriptors.shape[1] != SIFT_DIM:
                raise ShapeError(f"{nm}: expected (N, {SIFT_DIM}) SIFT descriptors, got {f.descriptors.shape}")
        uv_a = prior.camera_a.undistort_points(np.asarray(feats_a.keypoints, np.float64))
        uv_b = prior.camera_b.undistort_points(np.asarray(feats_b.keypoints, np.float64))
        s = self.settings
        return guided_ratio_match(feats_a.descriptors, feats_b.descriptors, uv_a, uv_b, prior, g, s.ratio, s.mutual)
