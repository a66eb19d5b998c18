"""Frame and pair statuses, and the one place a frame's status is decided.

One enum per concept: :class:`~triangulation.PointStatus` (a triangulated point),
:class:`PairStatus` (one frame pair), :class:`~vio_depth.rescale.FitStatus` (one robust
fit), :class:`~vio_depth.rescale.FitSource` (which fallback stage gave the fit used) and
:class:`FrameStatus` (the frame). Decisions compare these enums, never reason texts;
the reasons are rendered from data for people to read.
"""

from __future__ import annotations

import enum

from ..rescale import FitSource, FitStatus


class FrameStatus(str, enum.Enum):
    """Outcome of one frame. Anything other than OK / FALLBACK_* means no metric depth."""

    OK = "ok"
    FALLBACK_SCALE_ONLY = "fallback_scale_only"
    FALLBACK_PREVIOUS_FIT = "fallback_previous_fit"
    NO_PAIR = "no_pair"
    NO_POSE = "no_pose"
    POSE_INCONSISTENT = "pose_inconsistent"  # the images disagree with the frame's poses beyond their uncertainty
    TOO_FEW_MATCHES = "too_few_matches"
    TOO_FEW_POINTS = "too_few_points"
    ILL_CONDITIONED = "ill_conditioned"
    NO_CONSENSUS = "no_consensus"
    UNCERTAIN_FIT = "uncertain_fit"  # the fit's predicted error exceeds the stated bound
    NO_DISPARITY = "no_disparity"
    INVALID_DISPARITY = "invalid_disparity"  # a map that cannot give depth (vio_depth.disparity.validity)
    CORRUPT_IMAGE = "corrupt_image"  # the image's compressed data are damaged: the frame is skipped

    @property
    def has_depth(self) -> bool:
        return self in (FrameStatus.OK, FrameStatus.FALLBACK_SCALE_ONLY, FrameStatus.FALLBACK_PREVIOUS_FIT)


class PairStatus(str, enum.Enum):
    """Outcome of matching and triangulating one frame pair."""

    OK = "ok"  # at least one point passed every check
    TOO_FEW_MATCHES = "too_few_matches"  # fewer matches than ``min_matches``: not triangulated
    NO_VALID_POINTS = "no_valid_points"  # triangulated, but no point passed the checks
    POSE_INCONSISTENT = "pose_inconsistent"  # the matches disagree with the stated pose: not triangulated


_FROM_FIT_SOURCE = {
    FitSource.FRAME: FrameStatus.OK,
    FitSource.SCALE_ONLY: FrameStatus.FALLBACK_SCALE_ONLY,
    FitSource.PREVIOUS_FIT: FrameStatus.FALLBACK_PREVIOUS_FIT,
}
_FROM_FIT_STATUS = {
    FitStatus.TOO_FEW_POINTS: FrameStatus.TOO_FEW_POINTS,
    FitStatus.ILL_CONDITIONED: FrameStatus.ILL_CONDITIONED,
    FitStatus.NO_CONSENSUS: FrameStatus.NO_CONSENSUS,
    FitStatus.OK: FrameStatus.UNCERTAIN_FIT,  # a good line whose predicted error is above the bound
}


def decide_frame_status(points_status: FrameStatus, fit_source: FitSource | None,
                        fit_status: FitStatus | None, disparity_usable: bool = True) -> FrameStatus:
    """The frame's status from its points stage and its rescaling.

    Args:
        points_status: OK when the points stage delivered points (else why not: NO_PAIR,
            NO_POSE, TOO_FEW_MATCHES, TOO_FEW_POINTS).
        fit_source: which fallback stage gave the fit used, or None when the frame had no
            disparity map (status NO_DISPARITY).
        fit_status: this frame's own fit status (when ``fit_source`` is NONE: why it failed).
        disparity_usable: False when the frame's disparity map failed a content check
            (:mod:`vio_depth.disparity.validity`): INVALID_DISPARITY, whatever else happened.
    """
    if fit_source is None:
        return FrameStatus.NO_DISPARITY
    if not disparity_usable:
        return FrameStatus.INVALID_DISPARITY
    if fit_source in _FROM_FIT_SOURCE:
        return _FROM_FIT_SOURCE[fit_source]  # depth (this frame's fit or a fallback)
    if points_status != FrameStatus.OK:
        return points_status  # no points: that is the reason, not the fit's
    return _FROM_FIT_STATUS.get(fit_status, FrameStatus.NO_CONSENSUS)
