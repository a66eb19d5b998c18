"""The streaming pipeline: frame -> features -> pair -> triangulated points -> fit -> metric depth.

One :class:`Pipeline` processes frames in order (``process(frame)``), keeping a bounded
keyframe buffer whose features were extracted once. Every per-frame failure is a
:class:`~vio_depth.types.FrameStatus` with a reason; nothing in here raises for a bad
frame (only for bad *input*, e.g. an unreadable image).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from triangulation import TriangulationSettings

from vio_core.checks import check_array
from .disparity import DisparitySource
from .keyframes import PAIRING_PRESETS, Keyframe, KeyframeBuffer, Motion, PairingSettings
from .poses import PoseSource
from .rescale import RescalerSettings
from .types import Frame, FrameResult, FrameStatus


@dataclass(frozen=True)
class PipelineSettings:
    """Everything that shapes a run, chosen by preset names where there are presets.

    Attributes:
        matcher: matcher preset name (see ``matchers.available_matchers()``).
        device: "cpu" / "cuda" for learned matchers; None = cuda when available.
        pairing: keyframe/pair selection thresholds.
        triangulation: per-point checks (:class:`triangulation.TriangulationSettings`).
        rescaler: robust fit, fallbacks and temporal filter (:class:`vio_depth.rescale.RescalerSettings`).
        min_matches: fewer matches than this in a pair -> status too_few_matches.
        points: "sfm" (triangulated points) or a reference source "lidar:N" / "random:N"
            sampled from ground-truth depth, for comparison on the same frames.
        points_seed: seed of the "random:N" reference source.
    """

    matcher: str = "sift"
    device: str | None = None
    pairing: PairingSettings = PAIRING_PRESETS["kitti"]
    triangulation: TriangulationSettings = field(default_factory=TriangulationSettings)
    rescaler: RescalerSettings = field(default_factory=RescalerSettings)
    min_matches: int = 20
    points: str = "sfm"
    points_seed: int = 0


@dataclass
class _PairOutcome:
    status: FrameStatus
    reason: str
    partner: int | None = None
    matches: int = 0
    motion: Motion | None = None
    weak: bool = False
    status_counts: dict = field(default_factory=dict)
    partners: list = field(default_factory=list)
    # merged valid points: (N, 2) px in the current image, (N,) metres, (N,) metres, (N,)
    uv: np.ndarray | None = None
    depth: np.ndarray | None = None
    sigma: np.ndarray | None = None
    confidence: np.ndarray | None = None


class Pipeline:
    """Streaming metric-depth pipeline over frames of one camera.

    Args:
        settings: see :class:`PipelineSettings`.
        pose_source: gives relative poses between frames (``vio_depth.poses``).
        disparity_source: gives each frame's affine-invariant disparity.
    """

    def __init__(self, settings: PipelineSettings, pose_source: PoseSource, disparity_source: DisparitySource):
        from .reference_points import parse_points_spec
        from .rescale import Rescaler

        self.settings = settings
        self.pose_source = pose_source
        self.disparity_source = disparity_source
        self.points_spec = parse_points_spec(settings.points)
        self.triangulation_settings = settings.triangulation
        self.rescaler = Rescaler(settings.rescaler)
        self.buffer = KeyframeBuffer(settings.pairing)
        self.matcher = None
        if self.points_spec.kind == "sfm":
            from matchers import create_matcher

            self.matcher = create_matcher(settings.matcher, device=settings.device)

    # ------------------------------------------------------------------ per frame
    def process(self, frame: Frame) -> FrameResult:
        """Process the next frame of the stream and return its result (with ``depth``)."""
        t0 = time.perf_counter()
        result = self._process(frame)
        result.seconds = time.perf_counter() - t0
        return result

    def _process(self, frame: Frame) -> FrameResult:
        features = None
        if self.matcher is not None:
            image = frame.image()  # read once: a model disparity source gets the same pixels
            features = self.matcher.extract(image)  # once per frame, kept if keyframe
            frame = replace(frame, load_image=lambda: image)
        disparity = self.disparity_source(frame)

        empty = np.zeros(0)
        uv, depth, sigma, weights = np.zeros((0, 2)), empty, None, None
        if self.points_spec.kind == "sfm":
            pair = self._pair_and_triangulate(frame, features)
            self._maybe_add_keyframe(frame, features)
            if pair.uv is not None:
                uv, depth, sigma, weights = pair.uv, pair.depth, pair.sigma, pair.confidence
        else:
            gt = frame.gt_depth()
            if gt is None:
                pair = _PairOutcome(FrameStatus.TOO_FEW_POINTS, f"--points {self.settings.points} needs ground-truth depth")
            else:
                pair = _PairOutcome(FrameStatus.OK, "")
                uv, depth = self.points_spec.sample(gt, seed=self.settings.points_seed + frame.index)

        extra = {"point_status": pair.status_counts} if pair.status_counts else {}
        if len(pair.partners) > 1:
            extra["partners"] = pair.partners
        if pair.weak:
            extra["weak_pair"] = True
        if pair.motion is not None:
            extra["pair_rotation_deg"] = round(pair.motion.rotation_deg, 3)
            extra["pair_translation_m"] = round(pair.motion.translation_m, 4)
        res = FrameResult(frame.index, frame.stem, pair.status, pair.reason, pair.partner, pair.matches,
                          triangulated=int(len(depth)), extra=extra)
        if disparity is None:
            res.status, res.reason = FrameStatus.NO_DISPARITY, "no disparity map for this frame"
            return res

        from .rescale import sample_bilinear

        d, inside = sample_bilinear(disparity, uv)
        outcome = self.rescaler.update(d[inside], depth[inside],
                                       None if sigma is None else sigma[inside],
                                       None if weights is None else weights[inside],
                                       disparity_map=disparity)
        res.extra["points_sampled"] = int(inside.sum())
        res.extra["rescale"] = outcome.status.value
        res.extra["fit_diagnostics"] = outcome.raw.to_json()
        res.inliers = int(outcome.n_inliers)
        res.disparity = disparity
        res.points_uv, res.points_depth = uv[inside], depth[inside]
        # issue 13 (exports): per-point uncertainty and inlier flags of this frame's own fit
        res.points_sigma = None if sigma is None else sigma[inside]
        own = outcome.scale_only if outcome.scale_only is not None and outcome.scale_only.ok else outcome.raw
        res.points_inlier = own.inliers if len(own.inliers) == len(res.points_depth) else None
        rescale_status = outcome.frame_status
        if pair.status == FrameStatus.OK or rescale_status.has_depth:
            # The pair worked (the fit decides), or a fallback gave depth despite a failed pair.
            res.status = rescale_status
            res.reason = "; ".join(r for r in (pair.reason, outcome.reason) if r)
        if outcome.fit is not None:
            fit = outcome.fit
            res.fit = fit
            res.alpha, res.beta = float(fit.alpha), float(fit.beta)
            # issue 13 (report): 1-sigma of the (alpha, beta) actually used (filtered / fallback), None if unknown
            res.extra["sigma_alpha"] = fit.sigma_alpha if np.isfinite(fit.sigma_alpha) else None
            res.extra["sigma_beta"] = fit.sigma_beta if np.isfinite(fit.sigma_beta) else None
            res.r2 = None if fit.r2 is None or not np.isfinite(fit.r2) else float(fit.r2)
            res.depth = outcome.metric_depth(disparity)
        return res

    # ------------------------------------------------------------------ pairing
    def _pair_and_triangulate(self, frame: Frame, features) -> _PairOutcome:
        """Pair ``frame`` with up to ``pairing.pairs_per_frame`` keyframes and merge their points.

        Qualifying keyframes (beyond the motion thresholds) are used newest first; when none
        qualifies and weak pairs are allowed, the keyframe with the largest translation is
        used. A current keypoint triangulated in several pairs keeps its most certain depth
        (smallest ``sigma_depth``).
        """
        from triangulation import triangulate_pair

        pairing = self.settings.pairing
        if len(self.buffer) == 0:
            return _PairOutcome(FrameStatus.NO_PAIR, "first frame: no keyframe to pair with yet")
        qualifying, weak, reasons = [], [], []
        for kf in self.buffer.newest_first():
            rel = self.pose_source.relative(kf.frame, frame)
            if not rel.ok:
                reasons.append(rel.reason)
                continue
            motion = Motion.from_transform(rel.T_kf_cur)
            (qualifying if motion.exceeds(pairing) else weak).append((kf, rel, motion))
        if not qualifying and not weak:
            return _PairOutcome(FrameStatus.NO_POSE, "; ".join(sorted(set(reasons))) or "no relative pose")
        candidates, is_weak = qualifying[: pairing.pairs_per_frame], False
        if not candidates:
            best = max(weak, key=lambda c: c[2].translation_m)
            if not pairing.allow_weak_pairs:
                return _PairOutcome(FrameStatus.NO_PAIR, (
                    f"no keyframe beyond {pairing.min_rotation_deg} deg / {pairing.min_translation_m} m "
                    f"(best: {best[2].rotation_deg:.1f} deg, {best[2].translation_m:.2f} m)"))
            candidates, is_weak = [best], True

        counts: dict[str, int] = {}
        merged = []  # (current keypoint indices, valid TriangulatedPoints) per pair
        n_matches, problems = 0, []
        for kf, rel, motion in candidates:
            m = self.matcher.match(features, kf.features)
            n_matches += len(m)
            if len(m) < self.settings.min_matches:
                problems.append(f"{len(m)} matches with keyframe {kf.frame.index} (< {self.settings.min_matches})")
                continue
            pts = triangulate_pair(
                features.keypoints[m.idx_a], kf.features.keypoints[m.idx_b],
                frame.camera, kf.frame.camera, rel.T_kf_cur, self.triangulation_settings,
                confidence=m.confidence, pose_covariance=rel.covariance,
            )
            for name, k in pts.status_counts().items():
                counts[name] = counts.get(name, 0) + k
            valid = pts.valid
            if valid.any():
                merged.append((m.idx_a[valid], pts.subset(valid)))
            else:
                problems.append(f"no point passed the checks with keyframe {kf.frame.index}")

        first_kf, _, first_motion = candidates[0]
        outcome = _PairOutcome(FrameStatus.OK, "", first_kf.frame.index, n_matches, motion=first_motion,
                               weak=is_weak, status_counts=counts,
                               partners=[kf.frame.index for kf, _, _ in candidates])
        if not merged:
            too_few = all("matches with" in p for p in problems)
            outcome.status = FrameStatus.TOO_FEW_MATCHES if too_few else FrameStatus.TOO_FEW_POINTS
            outcome.reason = "; ".join(problems) + (f" ({_fmt_counts(counts)})" if counts else "")
            return outcome
        idx = np.concatenate([i for i, _ in merged])
        uv = np.concatenate([p.uv for _, p in merged])
        depth = np.concatenate([p.depth for _, p in merged])
        sigma = np.concatenate([p.sigma_depth for _, p in merged])
        conf = np.concatenate([p.confidence for _, p in merged])
        keep = most_certain_per_keypoint(idx, sigma)
        outcome.uv, outcome.depth, outcome.sigma, outcome.confidence = uv[keep], depth[keep], sigma[keep], conf[keep]
        return outcome

    def _maybe_add_keyframe(self, frame: Frame, features) -> None:
        newest = self.buffer.newest
        if newest is None:
            self.buffer.push(Keyframe(frame, features))
            return
        rel = self.pose_source.relative(newest.frame, frame)
        if rel.ok and Motion.from_transform(rel.T_kf_cur).exceeds(self.settings.pairing, self.settings.pairing.keyframe_fraction):
            self.buffer.push(Keyframe(frame, features))


def most_certain_per_keypoint(keypoint_idx, sigma_depth) -> np.ndarray:
    """Indices that keep, for each distinct keypoint, its entry with the smallest sigma.

    Args:
        keypoint_idx: (N,) int, index of the current-frame keypoint of each point.
        sigma_depth: (N,) metres, the point's depth uncertainty.

    Returns:
        (K,) int indices into the inputs, one per distinct keypoint, sorted by keypoint.
    """
    idx = check_array("keypoint_idx", keypoint_idx, (None,), dtype="int")
    sigma = check_array("sigma_depth", sigma_depth, (len(idx),))
    order = np.lexsort((sigma, idx))
    first = np.ones(len(order), bool)
    first[1:] = idx[order][1:] != idx[order][:-1]
    return order[first]


def _fmt_counts(counts: dict) -> str:
    return ", ".join(f"{k}: {v}" for k, v in counts.items() if v)
