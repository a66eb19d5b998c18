"""Feature extraction and matching: OpenCV SIFT, learned matchers through kornia, KLT tracks.

A leaf layer: it imports only :mod:`vio_core` (and numpy, OpenCV; torch/kornia lazily).

=====================  ======================================================================
module                 job
=====================  ======================================================================
``base``               :class:`Features`, :class:`Matches`, :class:`MotionHint`, the :class:`Matcher` and
                       :class:`FrameTracker` protocols
``sift``               :class:`SiftMatcher`, :class:`SiftSettings`
``guided``             pose-guided matching in the epipolar band (:class:`GuidedSettings`)
``nearest``            exact two nearest neighbours of descriptors (float32, bfloat16 screen)
``learned_settings``   :class:`LearnedMatcherSettings`
``learned``            :class:`LearnedMatcher` (kornia, bundled weights)
``klt``                :class:`KltTracker` (KLT optical-flow tracks), :class:`KltSettings`
``weights``            locating and loading the bundled weights offline
``registry``           :data:`MATCHER_PRESETS`, :func:`create_matcher`
=====================  ======================================================================
"""

from .base import Features, FrameTracker, Matcher, Matches, MotionHint
from .guided import EpipolarPrior, GuidedSettings, PoseGuidedMatcher, guided_ratio_match
from .klt import KltSettings, KltTracker, TrackIds
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
    "FrameTracker",
    "KltSettings",
    "KltTracker",
    "GuidedSettings",
    "LearnedMatcherSettings",
    "Matcher",
    "MatcherSettings",
    "Matches",
    "MotionHint",
    "PoseGuidedMatcher",
    "SiftMatcher",
    "SiftSettings",
    "TrackIds",
    "available_matchers",
    "create_matcher",
    "guided_ratio_match",
    "uses_device",
]
