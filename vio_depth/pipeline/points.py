"""The points stage: metric points of a frame from two-view triangulation with keyframes.

For each frame, :class:`TwoViewPoints` pairs it with up to ``pairing.pairs_per_frame``
keyframes of a bounded buffer (features extracted once per frame and kept with the
keyframe) whose points are predicted precise enough, matches, tests the pose source's
metric relative pose against the matches, triangulates with it and merges the valid points
of all pairs, keeping each keypoint's most certain depth.
"""

from __future__ import annotations

import time

import numpy as np

from matchers import EpipolarPrior, Features, Matcher, PoseGuidedMatcher
from triangulation import (
    ConsistencySettings,
    PoseInflation,
    TriangulationSettings,
    pose_consistency,
    predicted_depth_error,
    triangulate_pair,
)
from vio_core.checks import check_array

from ..frame import Frame
from ..keyframes import Keyframe, KeyframeBuffer, Motion, PairingSettings
from ..poses import FramePose, PoseSource
from ..rescale import shared_depth_errors
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
        pose_source: metric relative poses between frames (with their covariance when the
            source states one).
        pairing: pair and keyframe selection.
        triangulation: per-point checks.
        min_matches: fewer matches in a pair -> the pair is not triangulated.
        consistency: how each pair's stated pose is tested against its matches and the
            stated uncertainty inflated where the images show it too small.

    Each pair with a stated pose covariance is tested (:func:`triangulation.pose_consistency`)
    before it is triangulated and pooled into the inflation
    (:class:`triangulation.PoseInflation`): a pair whose images disagree with the pose beyond
    ``inflation x`` the stated uncertainty is refused (``pose_inconsistent``); the others
    are triangulated with the inflated covariance. Their points carry the depth sensitivities to the pose's
    error (``PointsOutcome.depth_shared``), so that the fit knows that error is shared.
    """

    def __init__(self, matcher: Matcher, pose_source: PoseSource, pairing: PairingSettings,
                 triangulation: TriangulationSettings, min_matches: int,
                 consistency: ConsistencySettings = ConsistencySettings()):
        self.matcher = matcher
        self.pose_source = pose_source
        self.pairing = pairing
        self.triangulation = triangulation
        self.min_matches = min_matches
        self.consistency = consistency
        self.buffer = KeyframeBuffer(pairing)
        self.inflation = PoseInflation(consistency)
        self._depth_hint = pairing.expected_depth_m

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

    def _predicted(self, frame: Frame, kf: Keyframe, rel) -> float:
        return predicted_depth_error(frame.camera, kf.frame.camera, rel.T_kf_cur, self._inflated(rel.covariance),
                                     self._depth_hint, self.triangulation.pixel_sigma_px)

    def _inflated(self, covariance):
        return None if covariance is None else self.inflation.value**2 * covariance

    def _choose(self, frame: Frame):
        """``(candidates, weak, outcome)``: the pairs to match, or an outcome saying why none.

        Keyframes beyond the motion thresholds are taken newest first, up to
        ``pairs_per_frame``, when their predicted precision is within ``max_pair_error``;
        when none is, the most precise keyframe within it is used as a weak pair."""
        pairing = self.pairing
        candidates, reasons = [], []
        qualifying = []  # newest first: beyond the motion thresholds and precise enough
        for kf in self.buffer.newest_first():
            rel = self.pose_source.relative(kf.frame, frame)
            if not rel.ok:
                reasons.append(rel.reason)
                continue
            motion = Motion.from_transform(rel.T_kf_cur)
            # the precision (the costly part) is predicted only where it can decide: for the
            # pairs beyond the thresholds until enough qualify; for the others when none does
            error = self._predicted(frame, kf, rel) if motion.exceeds(pairing) and \
                len(qualifying) < pairing.pairs_per_frame else None
            candidates.append([kf, rel, motion, error])
            if error is not None and error <= pairing.max_pair_error:
                qualifying.append(candidates[-1])
        if not candidates:
            return None, False, PointsOutcome(FrameStatus.NO_POSE, "; ".join(sorted(set(reasons))) or "no relative pose")
        if qualifying:
            return [tuple(c) for c in qualifying], False, None
        for c in candidates:
            if c[3] is None:
                c[3] = self._predicted(frame, c[0], c[1])
        precise = [c for c in candidates if c[3] <= pairing.max_pair_error]
        if precise and pairing.allow_weak_pairs:
            return [tuple(min(precise, key=lambda c: c[3]))], True, None
        best = min(candidates, key=lambda c: c[3])
        m = best[2]
        if not precise:
            what = (f"{m.rotation_deg:.1f} deg with {1000 * m.translation_m:.1f} mm of translation"
                    if m.translation_m < 0.01 * self._depth_hint else
                    f"{m.rotation_deg:.1f} deg, {m.translation_m:.3f} m")
            kind = "rotation only: " if m.translation_m < 0.01 * self._depth_hint else ""
            return None, False, PointsOutcome(FrameStatus.NO_PAIR, (
                f"{kind}no keyframe predicts points precise enough (best: keyframe {best[0].frame.index}, {what}, "
                f"predicted depth error {best[3]:.0%} at {self._depth_hint:.3g} m > max_pair_error "
                f"{pairing.max_pair_error:.0%})"))
        weak = "" if pairing.allow_weak_pairs else "; pairs below them are off (pairing.allow_weak_pairs)"
        return None, False, PointsOutcome(FrameStatus.NO_PAIR, (
            f"no keyframe beyond {pairing.min_rotation_deg} deg / {pairing.min_translation_m} m "
            f"(best: {m.rotation_deg:.1f} deg, {m.translation_m:.2f} m){weak}"))

    def _pair_and_triangulate(self, frame: Frame, features: Features) -> PointsOutcome:
        if len(self.buffer) == 0:
            return PointsOutcome(FrameStatus.NO_PAIR, "first frame: no keyframe to pair with yet")
        candidates, is_weak, refusal = self._choose(frame)
        if refusal is not None:
            return refusal

        attempts, merged = [], []  # merged: (current keypoint indices, valid TriangulatedPoints, covariance)
        clock = time.perf_counter
        timings = {"matching": 0.0, "triangulation": 0.0}
        for kf, rel, motion, predicted in candidates:
            t = clock()
            m = self._match(frame, features, kf, rel)
            timings["matching"] += clock() - t
            if len(m) < self.min_matches:
                attempts.append(PairAttempt(kf.frame.index, motion, len(m), PairStatus.TOO_FEW_MATCHES,
                                            T_kf_cur=rel.T_kf_cur, predicted_error=predicted))
                continue
            t = clock()
            uv_cur, uv_ref = features.keypoints[m.idx_a], kf.features.keypoints[m.idx_b]
            check = None
            if rel.covariance is not None:
                check = pose_consistency(uv_cur, uv_ref, frame.camera, kf.frame.camera, rel.T_kf_cur,
                                         rel.covariance, self.consistency, self.inflation.value)
                self.inflation.update(check)
                if check.tested and check.chi2 > self.consistency.threshold(check.dof):
                    timings["triangulation"] += clock() - t
                    attempts.append(PairAttempt(kf.frame.index, motion, len(m), PairStatus.POSE_INCONSISTENT,
                                                T_kf_cur=rel.T_kf_cur, predicted_error=predicted, consistency=check,
                                                pose_sigma=_sigmas(self._inflated(rel.covariance))))
                    continue
            cov = self._inflated(rel.covariance)
            pts = triangulate_pair(uv_cur, uv_ref, frame.camera, kf.frame.camera, rel.T_kf_cur, self.triangulation,
                                   confidence=m.confidence, pose_covariance=cov)
            timings["triangulation"] += clock() - t
            valid = pts.valid
            n_valid = int(valid.sum())
            attempts.append(PairAttempt(kf.frame.index, motion, len(m),
                                        PairStatus.OK if n_valid else PairStatus.NO_VALID_POINTS,
                                        pts.status_counts(), n_valid, rel.T_kf_cur, predicted, check, _sigmas(cov)))
            if n_valid:
                merged.append((m.idx_a[valid], pts.subset(valid), cov))

        inflation = self.inflation.value if any(a.consistency is not None for a in attempts) else None
        outcome = PointsOutcome(FrameStatus.OK, "", attempts, is_weak, timings=timings, pose_inflation=inflation)
        if not merged:
            counts = outcome.point_status
            if all(a.status == PairStatus.POSE_INCONSISTENT for a in attempts):
                outcome.status = FrameStatus.POSE_INCONSISTENT
            elif all(a.status == PairStatus.TOO_FEW_MATCHES for a in attempts):
                outcome.status = FrameStatus.TOO_FEW_MATCHES
            else:
                outcome.status = FrameStatus.TOO_FEW_POINTS
            outcome.reason = "; ".join(a.problem(self.min_matches) for a in attempts if a.problem(self.min_matches))
            outcome.reason += f" ({_fmt_counts(counts)})" if counts else ""
            return outcome
        idx = np.concatenate([i for i, _, _ in merged])
        sigma = np.concatenate([p.sigma_depth for _, p, _ in merged])
        keep = most_certain_per_keypoint(idx, sigma)
        outcome.uv = np.concatenate([p.uv for _, p, _ in merged])[keep]
        outcome.depth = np.concatenate([p.depth for _, p, _ in merged])[keep]
        outcome.sigma = sigma[keep]
        outcome.confidence = np.concatenate([p.confidence for _, p, _ in merged])[keep]
        if any(cov is not None for _, _, cov in merged):
            outcome.depth_shared = _shared_blocks([(p, cov) for _, p, cov in merged])[keep]
        if len(merged) >= 2:
            outcome.scale_agreement = scale_agreement(merged[0], merged[1])
        self._depth_hint = float(np.median(outcome.depth))
        return outcome

    def _match(self, frame: Frame, features: Features, kf: Keyframe, rel):
        """The pair's matches; a matcher that can use the known pose gets it with its stated
        (inflated) covariance (pose-guided matching, :mod:`matchers.guided`, where enabled)."""
        if isinstance(self.matcher, PoseGuidedMatcher):
            prior = EpipolarPrior(frame.camera, kf.frame.camera, rel.T_kf_cur, self._inflated(rel.covariance))
            return self.matcher.match_with_pose(features, kf.features, prior)
        return self.matcher.match(features, kf.features)

    def _maybe_add_keyframe(self, frame: Frame, features: Features, posed: bool = False) -> None:
        newest = self.buffer.newest
        if newest is None:
            self.buffer.push(Keyframe(frame, features))
            return
        rel = self.pose_source.relative(newest.frame, frame)
        if (rel.ok and Motion.from_transform(rel.T_kf_cur).exceeds(self.pairing, self.pairing.keyframe_fraction)) or (
                posed and not rel.ok):
            self.buffer.push(Keyframe(frame, features))


def scale_agreement(a, b) -> tuple[float, float, int] | None:
    """How well two pairs of one frame agree on the scale of the keypoints both triangulated.

    ``a``, ``b``: ``(keypoint indices (N,), valid TriangulatedPoints, pose covariance or
    None)`` of each pair. Returns ``(r, sigma_r, n)``: the median log depth ratio over the
    ``n`` common keypoints and its predicted 1-sigma from the two poses' stated errors (each
    pair's pose error moves its points together) and the points' own noise; None with
    fewer than 10 common keypoints. Two keyframes with independent pose errors see the
    translation's *length* -- which no two-view epipolar test can -- through this ratio.
    """
    (ia, pa, ca), (ib, pb, cb) = a, b
    common, xa, xb = np.intersect1d(ia, ib, return_indices=True)
    if len(common) < 10:
        return None
    za, zb = pa.depth[xa], pb.depth[xb]
    r = float(np.median(np.log(za / zb)))
    var = float(np.median((pa.sigma_depth[xa] / za) ** 2 + (pb.sigma_depth[xb] / zb) ** 2)) * (np.pi / 2) / len(common)
    for p, x, z, cov in ((pa, xa, za, ca), (pb, xb, zb, cb)):
        if cov is not None and p.depth_pose_jacobian is not None:
            g = np.mean(shared_depth_errors(p.depth_pose_jacobian[x], cov) / z[:, None], axis=0)
            var += float(g @ g)
    return r, float(np.sqrt(var)), int(len(common))


def _sigmas(covariance) -> tuple[float, float] | None:
    """``(rotation deg, translation m)``: the largest 1-sigma per axis of a (6, 6) pose covariance."""
    if covariance is None:
        return None
    var = np.diag(covariance)
    return float(np.degrees(np.sqrt(var[:3].max()))), float(np.sqrt(var[3:].max()))


def _shared_blocks(pairs) -> np.ndarray:
    """(N, 6 P): each pair's points' sensitivities to its own pose error, in its own six
    columns (pose errors of different pairs are independent); zeros for an exact pose."""
    n = sum(len(p) for p, _ in pairs)
    out = np.zeros((n, 6 * len(pairs)))
    row = 0
    for k, (p, cov) in enumerate(pairs):
        if cov is not None and p.depth_pose_jacobian is not None:
            out[row:row + len(p), 6 * k:6 * k + 6] = shared_depth_errors(p.depth_pose_jacobian, cov)
        row += len(p)
    return out
