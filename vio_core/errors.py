"""One error hierarchy for everything vio-depth raises on purpose.

The CLI turns any :class:`VioDepthError` into one line on stderr and exit code 1.
Failures *inside* the per-frame hot loop are statuses with reasons
(see :class:`vio_depth.pipeline.FrameStatus`), never exceptions.
"""

from __future__ import annotations


class VioDepthError(Exception):
    """Root of all errors raised deliberately by vio-depth."""


class InputError(VioDepthError):
    """Bad user input: a missing folder, an unreadable file, a wrong shape."""


class SequenceFormatError(InputError):
    """A sequence file is malformed. The message names the file (and line when known)."""

    def __init__(self, path, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class CorruptImageError(SequenceFormatError):
    """An image file whose compressed data are damaged (the decoder reported corrupt data).

    Inside a run this is a per-frame status (``corrupt_image``: the frame is skipped), not
    an error: one damaged frame of a long robot log must not end the run.
    """


class ShapeError(InputError, ValueError):
    """An array argument has the wrong shape, dtype or non-finite values."""


class NumericalError(VioDepthError):
    """A numerical failure of an estimator -- not the user's fault.

    E.g. an indeterminant linear system while marginalising a keyframe of the landmark
    window, or a refined estimate that is no longer finite. Where such a failure is an
    expected outcome of the per-frame loop (the odometry loses track), the caller turns it
    into a status with a reason; it is never an :class:`InputError`, which means bad input.
    """


class SettingsError(VioDepthError, ValueError):
    """A settings value is out of range (e.g. a negative threshold)."""


class UnknownNameError(SettingsError):
    """An unknown preset/registry name (a :class:`SettingsError`, hence a ValueError).
    The message lists the valid names."""

    def __init__(self, kind: str, name: str, valid):
        self.kind = kind
        self.name = name
        self.valid = sorted(valid)
        super().__init__(f"unknown {kind} {name!r}; valid names: {', '.join(self.valid)}")


class MissingDependencyError(VioDepthError, ImportError):
    """An optional dependency is not installed. The message says how to install it."""

    def __init__(self, package: str, extra: str, purpose: str):
        super().__init__(
            f"{purpose} needs the optional package {package!r}, which is not installed; "
            f"install it with: pip install -e '.[{extra}]' (see README.md)"
        )


def lookup(kind: str, name: str, table):
    """``table[name]``, or :class:`UnknownNameError` naming ``kind`` and listing the valid names.

    The one way presets and registries are chosen by name (CLI and API alike).
    """
    try:
        return table[name]
    except (KeyError, TypeError):
        raise UnknownNameError(kind, name, table) from None


class WorkerError(VioDepthError):
    """A worker process (e.g. the landmark window's, :mod:`vio_depth.landmarks.backend`) died
    or failed unexpectedly. The message carries the worker's own traceback when it had one."""
