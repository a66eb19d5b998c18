"""Feature extraction and matching: OpenCV SIFT and learned matchers through kornia.

A leaf layer: it imports only :mod:`vio_core` (and numpy, OpenCV; torch/kornia lazily).

=====================  ======================================================================
module                 job
=====================  ======================================================================
``base``               :class:`Features`, :class:`Matches`, the :class:`Matcher` protocol
``sift``               :class:`SiftMatcher`, :class:`SiftSettings`
``guided``             pose-guided matching in the epipolar band (:class:`GuidedSettings`)
``nearest``            exact two nearest neighbours of descriptors (float32, bfloat16 screen)
``learned_settings``   :class:`LearnedMatcherSettings`
``learned``            :class:`LearnedMatcher` (kornia, bundled weights)
``weights``            locating and loading the bundled weights offline
``registry``           :data:`MATCHER_PRESETS`, :func:`create_matcher`
=====================  ======================================================================
"""

from .base import Features, Matcher, Matches
from .guided import EpipolarPrior, GuidedSettings, PoseGuidedMatcher, guided_ratio_match
from .learned_settings import LearnedMatcherSettings
from .registry import (
    MATCHER_PRESETS,
    MatcherSettings,
    available_matchers,
    create_matcher,
    uses_device,
)
from .sift import SiftMatcher, SiftSettings

__all__ = [
    "MATCHER_PRESETS",
    "EpipolarPrior",
    "Features",
    "GuidedSettings",
    "LearnedMatcherSettings",
    "Matcher",
    "MatcherSettings",
    "Matches",
    "PoseGuidedMatcher",
    "SiftMatcher",
    "SiftSettings",
    "available_matchers",
    "create_matcher",
    "guided_ratio_match",
    "uses_device",
]
