"""One registry of matcher presets, chosen by name on the CLI and in the API.

Entries are ``"module:factory"`` strings so that listing or choosing ``"sift"`` never
imports torch or kornia; a learned preset imports them only when it is created.
"""

from __future__ import annotations

import importlib
from typing import Callable

from vio_core.errors import lookup

from .base import Matcher

# name -> "module:callable"; the callable takes (device: str | None) and returns a Matcher.
_PRESETS: dict[str, str] = {
    "sift": "matchers.sift:create_sift",
    "disk+lightglue": "matchers.learned:create_disk_lightglue",
    "aliked+lightglue": "matchers.learned:create_aliked_lightglue",
    "xfeat+lighterglue": "matchers.learned:create_xfeat_lighterglue",
}


def register_matcher(name: str, target: str | Callable[..., Matcher]) -> None:
    """Register a preset: ``target`` is a factory or a lazy ``"module:callable"`` string."""
    _PRESETS[name] = target


def available_matchers() -> list[str]:
    """Names of all registered presets (learned ones may still need their extras)."""
    return sorted(_PRESETS)


def create_matcher(name: str, device: str | None = None) -> Matcher:
    """Instantiate preset ``name``.

    Args:
        name: a name from :func:`available_matchers`.
        device: "cpu" or "cuda" for learned matchers (None = cuda when available);
            ignored by SIFT.

    Raises:
        UnknownNameError (a ValueError): unknown name; the message lists valid names.
        MissingDependencyError: a learned preset whose extra is not installed.
    """
    target = lookup("matcher", name, _PRESETS)
    if isinstance(target, str):
        module, attr = target.split(":")
        target = getattr(importlib.import_module(module), attr)
    return target(device=device) if _accepts_device(target) else target()


def _accepts_device(factory) -> bool:
    import inspect

    try:
        return "device" in inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return False
