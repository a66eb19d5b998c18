"""Matcher contract and domain types shared by every feature matcher.

A matcher is used in two steps so that features are computed **once per frame**:

    feats = matcher.extract(image)          # once, kept with the keyframe
    m = matcher.match(feats_a, feats_b)      # for every pair the frame takes part in
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array


@dataclass(frozen=True)
class Features:
    """Keypoints of one image.

    Attributes:
        keypoints: (N, 2) float32 pixels in the full-resolution *raw* image (x right, y down).
        descriptors: (N, D) descriptors (float32 for SIFT), or an empty (N, 0) array
            when the matcher keeps its own representation in ``payload``.
        scores: (N,) float32 detector responses (bigger = stronger).
        image_size: (width, height) pixels of the image they came from.
        payload: matcher-private data (e.g. torch tensors for LightGlue), may be empty.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    scores: np.ndarray
    image_size: tuple[int, int]
    payload: Any = field(default=None, repr=False)

    def __post_init__(self):
        kp = check_array("keypoints", self.keypoints, (None, 2))
        check_array("descriptors", self.descriptors, (len(kp), None), dtype=None)
        check_array("scores", self.scores, (len(kp),))

    def __len__(self) -> int:
        return len(self.keypoints)


@dataclass(frozen=True)
class Matches:
    """Correspondences between features ``a`` and ``b``.

    Attributes:
        idx_a: (M,) int64 indices into features a.
        idx_b: (M,) int64 indices into features b.
        confidence: (M,) float32 in [0, 1]; for SIFT derived from the ratio test.
    """

    idx_a: np.ndarray
    idx_b: np.ndarray
    confidence: np.ndarray

    def __post_init__(self):
        a = check_array("idx_a", self.idx_a, (None,), dtype="int")
        check_array("idx_b", self.idx_b, (len(a),), dtype="int")
        check_array("confidence", self.confidence, (len(a),))

    def __len__(self) -> int:
        return len(self.idx_a)

    @classmethod
    def empty(cls) -> "Matches":
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


@runtime_checkable
class Matcher(Protocol):
    """What the pipeline needs of a matcher."""

    name: str

    def extract(self, image: np.ndarray) -> Features:
        """Features of ``image: (H, W, 3) uint8 RGB``."""

    def match(self, feats_a: Features, feats_b: Features) -> Matches:
        """Correspondences between two feature sets from :meth:`extract`."""


@dataclass(frozen=True)
class MotionHint:
    """What is known of the camera's motion since the previous tracked frame.

    Attributes:
        camera: the camera of both images (its distortion is respected).
        R_cur_prev: (3, 3) rotation of the previous camera into the current one
            (``x_cur = R_cur_prev @ x_prev`` for a direction), e.g. integrated from the
            gyroscope; None when unknown.
    """

    camera: Camera
    R_cur_prev: np.ndarray | None = None

    def __post_init__(self):
        if self.R_cur_prev is not None:
            check_array("R_cur_prev", self.R_cur_prev, (3, 3), finite=True)


@runtime_checkable
class FrameTracker(Matcher, Protocol):
    """A matcher that follows features from one frame to the next (KLT): its features of a
    frame depend on the previous frame's, so frames must come to :meth:`track` in order."""

    def track(self, image: np.ndarray, hint: MotionHint | None = None) -> Features:
        """Features of the next frame ``image: (H, W, 3) uint8 RGB``, followed from the previous one."""

    def reset(self) -> None:
        """Forget the previous frame: the next :meth:`track` starts new tracks."""
