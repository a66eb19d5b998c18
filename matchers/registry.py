"""The matcher presets, chosen by name on the CLI and in the API.

A preset is a settings object (:class:`~matchers.sift.SiftSettings` or
:class:`~matchers.learned_settings.LearnedMatcherSettings`); :func:`create_matcher` builds
the matcher for a settings object or a preset name. Neither listing nor choosing a preset
imports torch or kornia; building a learned matcher does.
"""

from __future__ import annotations

from dataclasses import replace

from vio_core.errors import SettingsError
from vio_core.settings import Presets

from .base import Matcher
from .klt import KltSettings, KltTracker
from .learned import LearnedMatcher
from .learned_settings import LearnedMatcherSettings
from .sift import SiftMatcher, SiftSettings

MatcherSettings = SiftSettings | LearnedMatcherSettings | KltSettings

#: Named matcher presets (``--matcher``).
MATCHER_PRESETS: Presets = Presets("matcher", {
    "sift": SiftSettings(),
    "disk+lightglue": LearnedMatcherSettings(extractor="disk", max_side=1024, detection_threshold=0.0),
    "aliked+lightglue": LearnedMatcherSettings(extractor="aliked", max_side=1024, detection_threshold=0.2),
    "xfeat+lighterglue": LearnedMatcherSettings(extractor="xfeat", max_side=640, detection_threshold=0.05),
    "klt": KltSettings(),
}, default="sift", descriptions={
    "sift": "OpenCV SIFT, RootSIFT, two-way ratio test + mutual nearest neighbour (CPU)",
    "disk+lightglue": "DISK + LightGlue (kornia, bundled weights)",
    "aliked+lightglue": "ALIKED + LightGlue (kornia, bundled weights)",
    "xfeat+lighterglue": "XFeat + LighterGlue (kornia, bundled weights)",
    "klt": "KLT optical-flow tracks, gyroscope-predicted; matches join track ids (frames in order)",
})

def available_matchers() -> list[str]:
    """Names of all presets (learned ones may still need their extras)."""
    return sorted(MATCHER_PRESETS)


def uses_device(settings) -> bool:
    """Whether the matcher for ``settings`` runs on a selectable device (learned matchers)."""
    return hasattr(settings, "device")


def create_matcher(settings: "MatcherSettings | str", device: str | None = None) -> Matcher:
    """Build the matcher for ``settings`` (a settings object or a preset name).

    Args:
        settings: e.g. ``SiftSettings(ratio=0.7)`` or ``"disk+lightglue"``.
        device: "cpu" / "cuda" for matchers that have a device (None = the settings' own);
            a matcher without one (SIFT) refuses any device but "cpu".

    Raises:
        UnknownNameError (a ValueError): unknown name; the message lists valid names.
        SettingsError: a device for a matcher that has none.
        MissingDependencyError: a learned preset whose extra is not installed.
    """
    if isinstance(settings, str):
        settings = MATCHER_PRESETS[settings]
    if device is not None:
        if uses_device(settings):
            settings = replace(settings, device=device)
        elif device != "cpu":
            raise SettingsError(f"device {device!r} does not apply to the {type(settings).__name__} matcher "
                                "(it runs on the CPU)")
    match settings:
        case SiftSettings():
            return SiftMatcher(settings)
        case LearnedMatcherSettings():
            return LearnedMatcher(settings)
        case KltSettings():
            return KltTracker(settings)
    raise SettingsError(f"no matcher for settings of type {type(settings).__name__}; valid: SiftSettings, "
                        f"LearnedMatcherSettings, KltSettings (presets {', '.join(MATCHER_PRESETS)})")
