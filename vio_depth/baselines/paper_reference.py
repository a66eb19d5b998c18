"""The paper's published structure-from-motion rescaling, re-implemented as a baseline.

"paper-reference" reproduces the choices of the code published with the paper ("A Simple
yet Effective Test-Time Adaptation for Zero-Shot Monocular Metric Depth Estimation",
repository ENSTA-U2IS-AI/depth-rescaling: ``metric_depth/zoedepth/utils/rescaling.py``
``get_sift_matching_keypoints``, ``SFM_kitti``/``SFM_ddad``, ``RescalerPC``, and the
KITTI/DDAD data loaders), so that `vio-depth eval` and the benchmarks can put its figures
next to ours on the same frames and the same disparity. Per evaluated frame ``i``:

1. **Pair** (paper, Experiments: "image couples with a rotation higher than 5 degrees or a
   translation greater than 1.5 and 2 meters for KITTI and DDAD"): the partner is the
   newest earlier frame ``j`` (at most ``max_lookback`` frames back) whose relative pose
   to ``i``, from the sequence's metric poses, has a rotation > ``min_rotation_deg`` or a
   translation > ``min_translation_m``. **A frame without such a partner is dropped**
   (status ``no_pair``, no depth), as the published evaluation skips every frame whose
   pair fails the rule.
2. **Features re-extracted for the pair**: OpenCV SIFT at its defaults (no keypoint cap)
   on both images, grey = ``uint8(255 * (0.2125 R + 0.7154 G + 0.0721 B))`` (scikit-image's
   ``rgb2gray``, as published), nothing cached between pairs.
3. **FLANN matching without a ratio test**: KD-tree index with 2 trees, 50 checks,
   ``knnMatch(current, partner, k=2)`` and the nearest neighbour taken for *every*
   keypoint of the current image (no ratio test, no mutual check, no geometric check).
4. **Triangulation without checks**: ``cv2.triangulatePoints`` with ``P_cur = K [I | 0]``
   and ``P_partner = K [R | t]`` from ``T_partner_cur``; the points are in the current
   camera. The only filter is the published one, ``z > min_depth`` (1e-3 m, the
   ``min_depth`` of the published KITTI config): no epipolar, reprojection, parallax or
   depth-range check.
5. **Fit**: the disparity is sampled bilinearly at the current keypoints
   (``cv2.remap``, as published) and scikit-learn ``RANSACRegressor(LinearRegression())``
   at its defaults regresses ``1/z`` on it (threshold = median absolute deviation of the
   targets, 100 trials, no weights, no ``alpha > 0`` constraint).
6. **Depth**: ``D = 1 / (|alpha d + beta| + 1e-3)`` everywhere, as published (the
   ``abs()`` mirrors negative metric disparities to positive depths).

Where this departs from the published code, and why:

* ``random_state``: published ``None`` (unseeded); here a seed derived from
  ``settings.seed`` and the frame index, and ``cv2.setRNGSeed`` of the same value before
  FLANN (whose randomised KD-trees otherwise give different matches on every call: 13-16 %
  of the nearest neighbours changed between calls on a street frame), so that runs are
  reproducible and identical whichever executor runs them.
* Non-finite sampled disparities are dropped before the fit (scikit-learn rejects NaN; the
  SIMULATED disparity of KITTI / 7-Scenes is NaN outside the convex hull of the ground
  truth, a Depth Anything map never is).
* The pair rule searches back up to ``max_lookback`` frames for the newest qualifying
  partner (default: no limit). The published loaders only ever try the *immediately
  previous* frame (KITTI: image number - 1; DDAD: DGP ``back_context=1``) and drop the
  frame when that pair fails the rule; preset ``published_kitti`` / ``published_ddad``
  (``max_lookback=1``) reproduces that exactly. With it, a sequence moving less than
  1.5 m and 5 degrees per frame gets no depth at all (sample ``street``: 0.40-0.80 m and
  at most 3.5 degrees per frame), which is why the default searches back.
* The published KITTI loader runs SIFT on the 352 x 1216 KB-cropped images but
  triangulates with the uncropped ``P_rect`` intrinsics (principal point off by the crop
  margins); that bug is not reproduced: keypoints and intrinsics are in the same image.
* Keypoints are not undistorted (as published; KITTI and DDAD images are rectified);
  ``undistort_keypoints=True`` undistorts them with the sequence's camera.

`vio-depth eval --variants paper-reference` (:mod:`vio_depth.experiments`) scores it with
the project's metrics next to our variants on the same frames; ``benchmarks/bench_paper_reference.py``
prints it next to the oracle for one sequence. Needs scikit-learn (extra ``baselines``).
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError, MissingDependencyError, SettingsError, lookup
from vio_core.geometry import invert_transform

from ..disparity import DisparitySettings, create_disparity_source

#: scikit-image ``rgb2gray`` weights (ITU-R BT.709 luma), used by the published code
RGB2GRAY_WEIGHTS = np.array([0.2125, 0.7154, 0.0721])
#: added to ``|alpha d + beta|`` before inverting, as published (1/m)
PUBLISHED_DEPTH_EPS = 1e-3


@dataclass(frozen=True)
class PaperReferenceSettings:
    """Choices of the paper-reference baseline (see the module docstring).

    Attributes:
        min_rotation_deg: a pair qualifies when its relative rotation exceeds this (degrees).
        min_translation_m: ... or when its relative translation exceeds this (metres).
        max_lookback: partners are searched among the ``max_lookback`` previous frames
            (newest first); 1 = only the immediately previous frame (published loaders);
            None = every earlier frame.
        min_depth: metres; triangulated points with ``z <= min_depth`` are dropped
            (published ``RescalerPC``; 1e-3 is the published KITTI config value).
        flann_trees: KD-trees of the FLANN index (published: 2).
        flann_checks: leaves checked per FLANN query (published: 50).
        seed: base seed of FLANN and RANSAC (published: unseeded).
        undistort_keypoints: undistort keypoints with the camera before triangulation
            (published: no).
    """

    min_rotation_deg: float = 5.0
    min_translation_m: float = 1.5
    max_lookback: int | None = None
    min_depth: float = 1e-3
    flann_trees: int = 2
    flann_checks: int = 50
    seed: int = 0
    undistort_keypoints: bool = False

    def __post_init__(self):
        if not (self.min_rotation_deg > 0 and self.min_translation_m > 0):
            raise SettingsError("paper-reference: min_rotation_deg and min_translation_m must be positive")
        if self.max_lookback is not None and self.max_lookback < 1:
            raise SettingsError(f"paper-reference: max_lookback must be >= 1 or None, got {self.max_lookback}")
        if not self.min_depth >= 0:
            raise SettingsError(f"paper-reference: min_depth must be >= 0, got {self.min_depth}")
        if self.flann_trees < 1 or self.flann_checks < 1:
            raise SettingsError("paper-reference: flann_trees and flann_checks must be >= 1")
        if self.seed < 0:
            raise SettingsError(f"paper-reference: seed must be >= 0, got {self.seed}")


#: Named presets. kitti / ddad: the paper's thresholds, newest qualifying earlier frame;
#: published_*: only the previous frame, as the published loaders; indoor: our indoor
#: translation threshold (not from the paper), for 7-Scenes and the room sample.
PAPER_REFERENCE_PRESETS: dict[str, PaperReferenceSettings] = {
    "kitti": PaperReferenceSettings(min_translation_m=1.5),
    "ddad": PaperReferenceSettings(min_translation_m=2.0),
    "indoor": PaperReferenceSettings(min_translation_m=0.15),
    "published_kitti": PaperReferenceSettings(min_translation_m=1.5, max_lookback=1),
    "published_ddad": PaperReferenceSettings(min_translation_m=2.0, max_lookback=1),
}


def paper_reference_preset(name: str, **overrides) -> PaperReferenceSettings:
    """Preset ``name`` of :data:`PAPER_REFERENCE_PRESETS` with optional field overrides."""
    return replace(lookup("paper-reference preset", name, PAPER_REFERENCE_PRESETS), **overrides)


class PaperReferenceStatus(str, enum.Enum):
    """Outcome of one frame; only OK has depth (the baseline has no fallbacks)."""

    OK = "ok"
    NO_POSE = "no_pose"
    NO_PAIR = "no_pair"
    NO_DISPARITY = "no_disparity"
    TOO_FEW_MATCHES = "too_few_matches"
    TOO_FEW_POINTS = "too_few_points"
    FIT_FAILED = "fit_failed"

    @property
    def has_depth(self) -> bool:
        return self is PaperReferenceStatus.OK


@dataclass
class PaperReferenceResult:
    """One frame of the baseline.

    Attributes:
        frame, stem: index in the sequence and image stem.
        status, reason: :class:`PaperReferenceStatus` and why.
        partner: index of the partner frame, or None.
        matches: FLANN matches (= SIFT keypoints of the current image).
        points: points fed to RANSAC (after ``z > min_depth`` and finite disparity).
        inliers: RANSAC inliers.
        alpha, beta: fitted ``1/D = alpha d + beta`` (1/m), or None.
        r2: coefficient of determination of ``1/z`` on ``d`` over the RANSAC inliers, or None.
        seconds: wall time of the frame (images, disparity, SIFT, matching,
            triangulation, fit, depth map); ``seconds_disparity`` of it in the disparity source.
        depth: (H, W) float32 metres, or None when the frame is dropped.
        disparity: (H, W) float32 disparity used (None when not computed).
        points_uv: (N, 2) px and points_depth: (N,) metres, the points fed to RANSAC.
    """

    frame: int
    stem: str
    status: PaperReferenceStatus
    reason: str = ""
    partner: int | None = None
    matches: int = 0
    points: int = 0
    inliers: int = 0
    alpha: float | None = None
    beta: float | None = None
    r2: float | None = None
    seconds: float = 0.0
    seconds_disparity: float = 0.0
    depth: np.ndarray | None = field(default=None, repr=False)
    disparity: np.ndarray | None = field(default=None, repr=False)
    points_uv: np.ndarray | None = field(default=None, repr=False)
    points_depth: np.ndarray | None = field(default=None, repr=False)

    @property
    def has_depth(self) -> bool:
        return self.status.has_depth

    def to_json(self) -> dict:
        return {
            "frame": self.frame, "stem": self.stem, "status": self.status.value, "reason": self.reason,
            "partner": self.partner, "matches": self.matches, "points": self.points, "inliers": self.inliers,
            "alpha": self.alpha, "beta": self.beta, "r2": self.r2, "seconds": round(self.seconds, 4),
            "seconds_disparity": round(self.seconds_disparity, 4),
        }


# ----------------------------------------------------------------------------- steps


def choose_partner(T_w_c, index: int, settings: PaperReferenceSettings) -> int | None:
    """The newest earlier frame that forms a qualifying pair with frame ``index``.

    Args:
        T_w_c: (N, 4, 4) camera-to-world poses in metres; a frame without a pose has NaN
            entries.
        index: the current frame, 0 <= index < N.
        settings: thresholds and ``max_lookback``.

    Returns:
        The partner's index, or None (no pose for ``index``, or no earlier frame within
        ``max_lookback`` has a pose and rotation > ``min_rotation_deg`` or translation >
        ``min_translation_m`` relative to it).
    """
    T = check_array("T_w_c", T_w_c, (None, 4, 4))
    if not 0 <= index < len(T):
        raise InputError(f"choose_partner: index {index} outside 0..{len(T) - 1}")
    if not np.all(np.isfinite(T[index])):
        return None
    first = 0 if settings.max_lookback is None else max(0, index - settings.max_lookback)
    cand = T[first:index][::-1]  # newest first
    if len(cand) == 0:
        return None
    posed = np.all(np.isfinite(cand), axis=(1, 2))
    T_c_w = invert_transform(T[index])
    rel = np.einsum("ij,njk->nik", T_c_w, np.where(posed[:, None, None], cand, np.eye(4)))
    trans = np.linalg.norm(rel[:, :3, 3], axis=1)
    cos = np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    rot = np.degrees(np.arccos(cos))
    ok = posed & ((rot > settings.min_rotation_deg) | (trans > settings.min_translation_m))
    hits = np.flatnonzero(ok)
    return None if len(hits) == 0 else index - 1 - int(hits[0])


def published_gray(image) -> np.ndarray:
    """(H, W) uint8 grey of an (H, W, 3) uint8 RGB image, as the published code computes it."""
    img = check_image("image", image, channels=3)
    return ((img.astype(np.float64) / 255.0) @ RGB2GRAY_WEIGHTS * 255.0).astype(np.uint8)


def sift_features(image) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV SIFT at its defaults on the published grey image.

    Returns:
        uv: (N, 2) float64 px keypoint positions; descriptors: (N, 128) float32 (raw SIFT).
    """
    kps, desc = cv2.SIFT_create().detectAndCompute(published_gray(image), None)
    uv = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return uv, (np.zeros((0, 128), np.float32) if desc is None else desc)


def flann_nearest(desc_query, desc_train, seed: int, trees: int = 2, checks: int = 50) -> np.ndarray:
    """Nearest train descriptor of every query descriptor (FLANN, **no ratio test**).

    Args:
        desc_query: (N, 128) float32 descriptors of the current image.
        desc_train: (M, 128) float32 descriptors of the partner image, M >= 2.
        seed: OpenCV RNG seed set before building the randomised KD-trees.
        trees, checks: FLANN KD-tree parameters (published: 2, 50).

    Returns:
        (N,) int64 index into ``desc_train`` for every query descriptor.
    """
    q = check_array("desc_query", desc_query, (None, None), dtype=np.float32)
    t = check_array("desc_train", desc_train, (None, q.shape[1]), dtype=np.float32)
    if len(t) < 2 or len(q) == 0:
        raise InputError(f"flann_nearest: need >= 2 train and >= 1 query descriptors, got {len(t)} and {len(q)}")
    cv2.setRNGSeed(int(seed))
    flann = cv2.FlannBasedMatcher(dict(algorithm=1, trees=int(trees)), dict(checks=int(checks)))
    knn = flann.knnMatch(q, t, k=2)  # k=2 as published; only the first neighbour is used
    return np.array([m[0].trainIdx for m in knn], dtype=np.int64)


def triangulate_unchecked(uv_cur, uv_partner, camera: Camera, T_partner_cur) -> np.ndarray:
    """``cv2.triangulatePoints`` of matched pixels, with no check of any kind.

    Args:
        uv_cur: (N, 2) px in the current image.
        uv_partner: (N, 2) px in the partner image.
        camera: intrinsics of both images.
        T_partner_cur: (4, 4) current-camera-to-partner-camera transform, metres.

    Returns:
        (N, 3) metres in the current camera frame (points behind either camera, at
        infinity (NaN/inf) or far off included).
    """
    a = check_array("uv_cur", uv_cur, (None, 2))
    b = check_array("uv_partner", uv_partner, (len(a), 2))
    T = check_transform("T_partner_cur", T_partner_cur)
    K = camera.K
    P_cur = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_partner = K @ T[:3, :]
    if len(a) == 0:
        return np.zeros((0, 3))
    X = cv2.triangulatePoints(P_cur, P_partner, a.T.astype(np.float64), b.T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        return (X[:3] / X[3]).T


def sample_disparity(disparity, uv) -> np.ndarray:
    """Bilinear samples of ``disparity: (H, W)`` at ``uv: (N, 2)`` px (``cv2.remap``, as published;
    0 outside the image, NaN propagates)."""
    d = check_image("disparity", disparity).astype(np.float32, copy=False)
    uv = check_array("uv", uv, (None, 2))
    if len(uv) == 0:
        return np.zeros(0)
    x = uv[:, 0].astype(np.float32).reshape(-1, 1)
    y = uv[:, 1].astype(np.float32).reshape(-1, 1)
    return cv2.remap(d, x, y, cv2.INTER_LINEAR)[:, 0].astype(np.float64)


@dataclass(frozen=True)
class SklearnFit:
    """Result of :func:`fit_sklearn_ransac`: ``1/D = alpha d + beta`` (1/m) and the inlier mask (N,)."""

    alpha: float
    beta: float
    inliers: np.ndarray


def fit_sklearn_ransac(d, depth, seed: int) -> SklearnFit:
    """scikit-learn ``RANSACRegressor(LinearRegression())`` at its defaults, seeded.

    Args:
        d: (N,) affine-invariant disparity at the points (finite).
        depth: (N,) metres, the points' depths (> 0).
        seed: ``random_state`` (the published code leaves it None).

    Raises:
        ValueError: from scikit-learn (e.g. no valid consensus set, too few points).
        MissingDependencyError: scikit-learn is not installed (extra ``baselines``).
    """
    try:
        from sklearn.linear_model import LinearRegression, RANSACRegressor
    except ImportError:
        raise MissingDependencyError("scikit-learn", "baselines", "the paper-reference baseline") from None

    d = check_array("d", d, (None,), finite=True)
    z = check_array("depth", depth, (len(d),), finite=True)
    model = RANSACRegressor(LinearRegression(), random_state=int(seed)).fit(d[:, None], 1.0 / z)
    return SklearnFit(float(model.estimator_.coef_[0]), float(model.estimator_.intercept_),
                      np.asarray(model.inlier_mask_, dtype=bool))


def published_depth(disparity, alpha: float, beta: float) -> np.ndarray:
    """``1 / (|alpha d + beta| + 1e-3)``: (H, W) float32 metres from ``disparity: (H, W)`` (NaN stays NaN)."""
    d = check_image("disparity", disparity).astype(np.float64)
    return (1.0 / (np.abs(alpha * d + beta) + PUBLISHED_DEPTH_EPS)).astype(np.float32)


def frame_seed(seed: int, index: int) -> int:
    """A 31-bit seed for frame ``index`` of a run seeded with ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0] >> 1)


# ----------------------------------------------------------------------------- frames


def default_disparity_source(sequence, seed: int = 0):
    """The sequence's own disparity, else the SIMULATED one from its ground truth.

    Raises:
        InputError: the sequence has neither disparity maps nor ground-truth depth.
    """
    if sequence.disparity is not None:
        return create_disparity_source(DisparitySettings(), sequence)
    if sequence.has_gt_depth:
        return create_disparity_source(DisparitySettings(source="simulated", seed=int(seed)), sequence)
    raise InputError(f"{sequence.root}: no disparity maps and no ground-truth depth to simulate them from")


def sequence_poses(sequence) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses of every frame (NaN where a frame has none)."""
    out = np.full((len(sequence), 4, 4), np.nan)
    for i in range(len(sequence)):
        T = sequence.frame(i).T_w_c
        if T is not None:
            out[i] = T
    return out


def process_frame(sequence, index: int, disparity_source, settings: PaperReferenceSettings,
                  poses=None) -> PaperReferenceResult:
    """Run the baseline on frame ``index`` of ``sequence``.

    Args:
        sequence: a :class:`vio_depth.io.Sequence` with poses.
        index: frame to process.
        disparity_source: ``source(frame) -> (H, W) disparity | None``.
        settings: :class:`PaperReferenceSettings`.
        poses: (N, 4, 4) :func:`sequence_poses` of ``sequence`` (computed when None).
    """
    t0 = time.perf_counter()
    frame = sequence.frame(index)
    poses = sequence_poses(sequence) if poses is None else poses

    def done(status, reason, **kw) -> PaperReferenceResult:
        return PaperReferenceResult(frame=index, stem=frame.stem, status=status, reason=reason,
                                    seconds=time.perf_counter() - t0, **kw)

    if frame.T_w_c is None:
        return done(PaperReferenceStatus.NO_POSE, "frame has no pose")
    partner = choose_partner(poses, index, settings)
    if partner is None:
        return done(PaperReferenceStatus.NO_PAIR,
                    f"no earlier frame with rotation > {settings.min_rotation_deg:g} deg or translation > "
                    f"{settings.min_translation_m:g} m" + ("" if settings.max_lookback is None
                                                            else f" within {settings.max_lookback} frame(s)"))
    t_d = time.perf_counter()
    disparity = disparity_source(frame)
    seconds_disparity = time.perf_counter() - t_d
    if disparity is None:
        return done(PaperReferenceStatus.NO_DISPARITY, "disparity source has no map for this frame",
                    partner=partner, seconds_disparity=seconds_disparity)
    other = sequence.frame(partner)
    uv_cur, desc_cur = sift_features(frame.image())
    uv_par, desc_par = sift_features(other.image())
    base = dict(partner=partner, seconds_disparity=seconds_disparity, disparity=disparity)
    if len(uv_cur) < 1 or len(uv_par) < 2:
        return done(PaperReferenceStatus.TOO_FEW_MATCHES,
                    f"{len(uv_cur)} / {len(uv_par)} SIFT keypoints in the frame / partner", **base)
    seed = frame_seed(settings.seed, index)
    nearest = flann_nearest(desc_cur, desc_par, seed, settings.flann_trees, settings.flann_checks)
    a, b = uv_cur, uv_par[nearest]
    if settings.undistort_keypoints:
        a, b = frame.camera.undistort_points(a), other.camera.undistort_points(b)
    T_partner_cur = invert_transform(other.T_w_c) @ frame.T_w_c
    points_c = triangulate_unchecked(a, b, frame.camera, T_partner_cur)
    z = points_c[:, 2]
    d = sample_disparity(disparity, uv_cur)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(z) & (z > settings.min_depth) & np.isfinite(d)
    base.update(matches=len(nearest), points=int(keep.sum()), points_uv=uv_cur[keep], points_depth=z[keep])
    if keep.sum() < 2:
        return done(PaperReferenceStatus.TOO_FEW_POINTS,
                    f"{int(keep.sum())} of {len(z)} triangulated points with z > {settings.min_depth:g} m "
                    "and a finite disparity", **base)
    try:
        fit = fit_sklearn_ransac(d[keep], z[keep], seed)
    except ValueError as exc:
        return done(PaperReferenceStatus.FIT_FAILED, f"RANSACRegressor: {exc}", **base)
    depth = published_depth(disparity, fit.alpha, fit.beta)
    m_in, d_in = 1.0 / z[keep][fit.inliers], d[keep][fit.inliers]
    ss_tot = float(np.sum((m_in - m_in.mean()) ** 2))
    r2 = 1.0 - float(np.sum((m_in - fit.alpha * d_in - fit.beta) ** 2)) / ss_tot if ss_tot > 0 else None
    return done(PaperReferenceStatus.OK, f"{int(fit.inliers.sum())} of {int(keep.sum())} points are RANSAC inliers",
                inliers=int(fit.inliers.sum()), alpha=fit.alpha, beta=fit.beta, r2=r2, depth=depth, **base)


def iter_paper_reference(sequence, disparity_source=None, settings: PaperReferenceSettings | None = None,
                         frames: Iterable[int] | None = None) -> Iterator[PaperReferenceResult]:
    """Yield one :class:`PaperReferenceResult` per frame of ``frames`` (default: all), in order.

    A generator, so that a caller evaluating each frame holds one depth map at a time.
    Partners may be any earlier frame of the sequence, also outside ``frames``.

    Args:
        sequence: a :class:`vio_depth.io.Sequence` with poses.
        disparity_source: ``source(frame) -> disparity``; None = :func:`default_disparity_source`.
        settings: None = preset ``kitti``.
        frames: indices to process (e.g. the KITTI Eigen split frames of one drive).
    """
    settings = PAPER_REFERENCE_PRESETS["kitti"] if settings is None else settings
    source = default_disparity_source(sequence, settings.seed) if disparity_source is None else disparity_source
    poses = sequence_poses(sequence)
    for index in (range(len(sequence)) if frames is None else frames):
        yield process_frame(sequence, int(index), source, settings, poses)


def run_paper_reference(sequence, disparity_source=None, settings: PaperReferenceSettings | None = None,
                        frames: Iterable[int] | None = None) -> list[PaperReferenceResult]:
    """All results of :func:`iter_paper_reference` as a list (keeps every depth map in memory)."""
    return list(iter_paper_reference(sequence, disparity_source, settings, frames))
