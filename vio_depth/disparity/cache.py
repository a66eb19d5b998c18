"""A disk cache in front of any disparity source, so several evaluations of a frame compute its map once.

``vio-depth eval`` runs every variant of a sequence as its own task (possibly in other
processes or on other machines); a SIMULATED disparity of real ground truth (densified
first) or a network costs about a second a frame, more than most variants themselves.
:class:`CachedDisparitySource` stores each map the first time it is computed, as
``<folder>/<key>/<index>_<stem>.npy`` with the map's own dtype (float32): a map read back is
bit-identical to the one computed, so results do not depend on which task computed it
first. Writes are atomic (temporary file + rename): concurrent workers that compute the
same frame write identical bytes, and a reader never sees half a file.

``key`` names the source: the caller derives it from everything that determines the maps
(sequence path, disparity settings, package version), e.g. with :func:`cache_key`.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from vio_core.errors import InputError

from ..frame import Frame
from .base import DisparitySource

#: file written instead of a map when the source has none for a frame
_NONE_SUFFIX = ".none"


def cache_key(*parts) -> str:
    """A 16-hex-digit key from JSON-able ``parts`` (sorted keys: dict order does not matter)."""
    text = json.dumps(parts, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class CachedDisparitySource:
    """``source`` with each frame's map stored under ``folder / key`` (see the module docstring).

    Args:
        source: any :class:`~vio_depth.disparity.DisparitySource`.
        folder: the cache root (created when missing).
        key: names the source; different sources must use different keys.

    Attributes:
        kind: the wrapped source's kind (a SIMULATED map stays labelled SIMULATED).
        hits, misses: maps read from the cache / computed, since construction.
    """

    def __init__(self, source: DisparitySource, folder, key: str):
        if not key or any(c in key for c in "/\\") or key.startswith("."):
            raise InputError(f"disparity cache key must be a plain file name, got {key!r}")
        self.source = source
        self.kind = source.kind
        self.folder = Path(folder) / key
        self.folder.mkdir(parents=True, exist_ok=True)
        self.hits = 0
        self.misses = 0

    def path_for(self, frame: Frame) -> Path:
        return self.folder / f"{int(frame.index):06d}_{frame.stem}.npy"

    def __call__(self, frame: Frame) -> np.ndarray | None:
        path = self.path_for(frame)
        none_marker = path.with_suffix(_NONE_SUFFIX)
        if none_marker.is_file():
            self.hits += 1
            return None
        if path.is_file():
            try:
                d = np.load(path, allow_pickle=False)
                self.hits += 1
                return d
            except (OSError, ValueError):
                pass  # a damaged entry is recomputed and replaced
        self.misses += 1
        d = self.source(frame)
        if d is None:
            _write_atomic(none_marker, lambda fh: None)
        else:
            _write_atomic(path, lambda fh: np.save(fh, d, allow_pickle=False))
        return d


def _write_atomic(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
