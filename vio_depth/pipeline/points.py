"""The points stage: metric points of a frame from two-view triangulation with keyframes.

For each frame, :class:`TwoViewPoints` pairs it with up to ``pairing.pairs_per_frame``
keyframes of a bounded buffer (features extracted once per frame and kept with the
keyframe), matches, triangulates with the pose source's metric relative pose, and merges
the valid points of all pairs, keeping each keypoint's most certain depth.
"""

from __future__ import annotations

import time

import numpy as np

from matchers import Features, Matcher
from triangulation import TriangulationSettings, triangulate_pair
from vio_core.checks import check_array

from ..frame import Frame
from ..keyframes import Keyframe, KeyframeBuffer, Motion, PairingSettings
from ..poses import FramePose, PoseSource
from .result import PairAttempt, PointsOutcome
from .status import FrameStatus, PairStatus


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


class TwoViewPoints:
    """Two-view SfM points with a keyframe buffer (one instance per stream of frames).

    Args:
        matcher: extracts and matches features.
        pose_source: metric relative poses between frames.
        pairing: pair and keyframe selection.
        triangulation: per-point checks.
        min_matches: fewer matches in a pair -> the pair is not triangulated.
    """

    def __init__(self, matcher: Matcher, pose_source: PoseSource, pairing: PairingSettings,
                 triangulation: TriangulationSettings, min_matches: int):
        self.matcher = matcher
        self.pose_source = pose_source
        self.pairing = pairing
        self.triangulation = triangulation
        self.min_matches = min_matches
        self.buffer = KeyframeBuffer(pairing)

    def process(self, frame: Frame, features: Features, frame_pose: FramePose | None = None) -> PointsOutcome:
        """Points of ``frame`` (whose ``features`` were just extracted); then maybe keep it as a keyframe.

        ``frame_pose``: a tracking pose source's own pose of the frame (None for the others).
        A frame it gives no pose gets ``no_pose`` with its reason, and is kept as a keyframe
        (the odometry may pose it later, e.g. the frames of its initialisation, and later
        frames then pair with it); a posed frame becomes one when the newest keyframe has no
        relative pose to it.
        """
        if frame_pose is not None and not frame_pose.ok:
            self.buffer.push(Keyframe(frame, features))
            return PointsOutcome(FrameStatus.NO_POSE, frame_pose.reason or "the pose source has no pose for this frame")
        outcome = self._pair_and_triangulate(frame, features)
        self._maybe_add_keyframe(frame, features, frame_pose is not None)
        return outcome

    def _pair_and_triangulate(self, frame: Frame, features: Features) -> PointsOutcome:
        """Qualifying keyframes (beyond the motion thresholds) are used newest first; when none
        qualifies and weak pairs are allowed, the keyframe with the largest translation is used."""
        pairing = self.pairing
        if len(self.buffer) == 0:
            return PointsOutcome(FrameStatus.NO_PAIR, "first frame: no keyframe to pair with yet")
        qualifying, weak, reasons = [], [], []
        for kf in self.buffer.newest_first():
            rel = self.pose_source.relative(kf.frame, frame)
            if not rel.ok:
                reasons.append(rel.reason)
                continue
            motion = Motion.from_transform(rel.T_kf_cur)
            (qualifying if motion.exceeds(pairing) else weak).append((kf, rel, motion))
        if not qualifying and not weak:
            return PointsOutcome(FrameStatus.NO_POSE, "; ".join(sorted(set(reasons))) or "no relative pose")
        candidates, is_weak = qualifying[: pairing.pairs_per_frame], False
        if not candidates:
            best = max(weak, key=lambda c: c[2].translation_m)
            if not pairing.allow_weak_pairs:
                return PointsOutcome(FrameStatus.NO_PAIR, (
                    f"no keyframe beyond {pairing.min_rotation_deg} deg / {pairing.min_translation_m} m "
                    f"(best: {best[2].rotation_deg:.1f} deg, {best[2].translation_m:.2f} m)"))
            candidates, is_weak = [best], True

        attempts, merged = [], []  # merged: (current keypoint indices, valid TriangulatedPoints) per pair
        clock = time.perf_counter
        timings = {"matching": 0.0, "triangulation": 0.0}
        for kf, rel, motion in candidates:
            t = clock()
            m = self.matcher.match(features, kf.features)
            timings["matching"] += clock() - t
            if len(m) < self.min_matches:
                attempts.append(PairAttempt(kf.frame.index, motion, len(m), PairStatus.TOO_FEW_MATCHES,
                                            T_kf_cur=rel.T_kf_cur))
                continue
            t = clock()
            pts = triangulate_pair(
                features.keypoints[m.idx_a], kf.features.keypoints[m.idx_b],
                frame.camera, kf.frame.camera, rel.T_kf_cur, self.triangulation,
                confidence=m.confidence, pose_covariance=rel.covariance,
            )
            timings["triangulation"] += clock() - t
            valid = pts.valid
            n_valid = int(valid.sum())
            attempts.append(PairAttempt(kf.frame.index, motion, len(m),
                                        PairStatus.OK if n_valid else PairStatus.NO_VALID_POINTS,
                                        pts.status_counts(), n_valid, rel.T_kf_cur))
            if n_valid:
                merged.append((m.idx_a[valid], pts.subset(valid)))

        outcome = PointsOutcome(FrameStatus.OK, "", attempts, is_weak, timings=timings)
        if not merged:
            counts = outcome.point_status
            too_few = all(a.status == PairStatus.TOO_FEW_MATCHES for a in attempts)
            outcome.status = FrameStatus.TOO_FEW_MATCHES if too_few else FrameStatus.TOO_FEW_POINTS
            outcome.reason = "; ".join(a.problem(self.min_matches) for a in attempts) + (
                f" ({_fmt_counts(counts)})" if counts else "")
            return outcome
        idx = np.concatenate([i for i, _ in merged])
        sigma = np.concatenate([p.sigma_depth for _, p in merged])
        keep = most_certain_per_keypoint(idx, sigma)
        outcome.uv = np.concatenate([p.uv for _, p in merged])[keep]
        outcome.depth = np.concatenate([p.depth for _, p in merged])[keep]
        outcome.sigma = sigma[keep]
        outcome.confidence = np.concatenate([p.confidence for _, p in merged])[keep]
        return outcome

    def _maybe_add_keyframe(self, frame: Frame, features: Features, posed: bool = False) -> None:
        newest = self.buffer.newest
        if newest is None:
            self.buffer.push(Keyframe(frame, features))
            return
        rel = self.pose_source.relative(newest.frame, frame)
        if (rel.ok and Motion.from_transform(rel.T_kf_cur).exceeds(self.pairing, self.pairing.keyframe_fraction)) or (
                posed and not rel.ok):
            self.buffer.push(Keyframe(frame, features))
