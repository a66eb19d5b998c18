"""Feature extraction and matching: OpenCV SIFT and learned matchers through kornia."""

from .base import Features, Matcher, Matches
from .registry import available_matchers, create_matcher, register_matcher

__all__ = ["Features", "Matcher", "Matches", "available_matchers", "create_matcher", "register_matcher"]
