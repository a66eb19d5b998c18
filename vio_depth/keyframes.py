"""Bounded keyframe buffer and the motion rule that pairs a frame with a keyframe.

The paper pairs an image with an earlier one when their relative rotation exceeds 5
degrees *or* their translation exceeds a threshold (1.5 m on KITTI, 2 m on DDAD).
We keep a small buffer of recent keyframes, each with its features extracted once,
so a frame can be paired with the newest keyframe that satisfies the rule instead of
only its direct predecessor -- and, unlike the paper's code, a frame whose motion is
below the threshold is not dropped outright: it is paired with the keyframe giving
the largest baseline and the per-point parallax check decides which points survive.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from matchers import Features
from vio_core.errors import SettingsError
from vio_core.geometry import rotation_angle_deg
from vio_core.settings import Presets

from .frame import Frame


@dataclass(frozen=True)
class PairingSettings:
    """When two frames form a pair and when a frame becomes a keyframe.

    Attributes:
        min_rotation_deg: a pair qualifies when the relative rotation exceeds this (degrees).
        min_translation_m: ... or when the relative translation exceeds this (metres).
        keyframe_fraction: a frame is added to the buffer when its motion relative to the
            newest keyframe exceeds this fraction of either threshold (the first frame
            always is). Smaller values keep more, closer keyframes.
        buffer_size: keyframes kept (oldest dropped first); bounds memory.
        pairs_per_frame: qualifying keyframes (newest first) a frame is matched with; their
            valid points are merged (features are cached, so an extra pair costs one
            matching and one triangulation, no extraction).
        allow_weak_pairs: when no keyframe is beyond the thresholds, pair with the one whose
            points are predicted most precise instead of giving up.
        max_pair_error: the deciding rule: a pair is used only when the relative depth sigma
            predicted for the better quarter of its image (:func:`triangulation.predicted_depth_error`:
            baseline, scene depth, pixel noise and the pose's stated uncertainty) is at most this. The
            rotation/translation thresholds above only pre-filter (and order) the
            candidates. A pure rotation predicts no precision at all: no pair, and the
            reason says so.
        expected_depth_m: scene depth assumed for that prediction until the first points
            (then the median depth of the last frame's points is used).
    """

    min_rotation_deg: float = 5.0
    min_translation_m: float = 1.5
    keyframe_fraction: float = 0.5
    buffer_size: int = 8
    pairs_per_frame: int = 2
    allow_weak_pairs: bool = True
    max_pair_error: float = 0.25
    expected_depth_m: float = 10.0

    def __post_init__(self):
        if not (0 < self.min_rotation_deg <= 180 and 0 < self.min_translation_m < math.inf):
            raise SettingsError("pairing thresholds must be finite and positive (--min-rotation in (0, 180] "
                                f"degrees, --min-translation metres), got min_rotation_deg={self.min_rotation_deg!r}, "
                                f"min_translation_m={self.min_translation_m!r}")
        if not 0 < self.keyframe_fraction <= 1:
            raise SettingsError("keyframe_fraction must be in (0, 1]")
        if self.buffer_size < 1 or self.pairs_per_frame < 1:
            raise SettingsError("buffer_size and pairs_per_frame must be >= 1")
        if not (0 < self.max_pair_error < math.inf and 0 < self.expected_depth_m < math.inf):
            raise SettingsError("max_pair_error and expected_depth_m must be finite and > 0, got "
                                f"{self.max_pair_error!r}, {self.expected_depth_m!r}")


#: Named pairing presets. "kitti"/"ddad" are the paper's thresholds; "indoor" scales the
#: translation threshold to room-sized scenes (depths of a few metres).
PAIRING_PRESETS: Presets = Presets("pairing preset", {
    "kitti": PairingSettings(min_rotation_deg=5.0, min_translation_m=1.5, expected_depth_m=15.0),
    "ddad": PairingSettings(min_rotation_deg=5.0, min_translation_m=2.0, expected_depth_m=20.0),
    "indoor": PairingSettings(min_rotation_deg=5.0, min_translation_m=0.15, expected_depth_m=2.0),
}, default="kitti", descriptions={
    "kitti": "5 deg / 1.5 m (the paper's KITTI threshold)",
    "ddad": "5 deg / 2 m (the paper's DDAD threshold)",
    "indoor": "5 deg / 0.15 m (room-sized scenes)",
})


def pairing_preset(name: str, **overrides) -> PairingSettings:
    """Preset ``name`` from :data:`PAIRING_PRESETS`, with optional field overrides."""
    return PAIRING_PRESETS.get_preset(name, **overrides)


@dataclass(frozen=True)
class Motion:
    """Relative motion between two frames: rotation (degrees), translation (metres)."""

    rotation_deg: float
    translation_m: float

    @classmethod
    def from_transform(cls, T_a_b) -> "Motion":
        """Motion of a (4, 4) relative transform ``T_a_b``."""
        T = np.asarray(T_a_b, dtype=float)
        return cls(rotation_angle_deg(T[:3, :3]), float(np.linalg.norm(T[:3, 3])))

    def exceeds(self, settings: PairingSettings, fraction: float = 1.0) -> bool:
        return (
            self.rotation_deg > fraction * settings.min_rotation_deg
            or self.translation_m > fraction * settings.min_translation_m
        )


@dataclass
class Keyframe:
    """A buffered frame with its features, extracted once when it was processed."""

    frame: Frame
    features: Features


class KeyframeBuffer:
    """Bounded buffer of the most recent keyframes (newest last)."""

    def __init__(self, settings: PairingSettings):
        self.settings = settings
        self._items: deque[Keyframe] = deque(maxlen=settings.buffer_size)

    def __len__(self) -> int:
        return len(self._items)

    def newest_first(self) -> Iterator[Keyframe]:
        return reversed(self._items)

    @property
    def newest(self) -> Keyframe | None:
        return self._items[-1] if self._items else None

    def push(self, keyframe: Keyframe) -> None:
        self._items.append(keyframe)
