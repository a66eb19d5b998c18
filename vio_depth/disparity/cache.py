"""A disk cache in front of any disparity source, so several evaluations of a frame compute its map once.

``vio-depth eval`` runs every variant of a sequence as its own task (possibly in other
processes or on other machines); a SIMULATED disparity of real ground truth (densified
first) or a network costs about a second a frame, more than most variants themselves.
:class:`CachedDisparitySource` stores each map the first time it is computed, as
``<folder>/<key>/<index>_<stem>.npy`` with the map's own dtype (float32): a map read back is
bit-identical to the one computed, so results do not depend on which task computed it
first. Writes are atomic (temporary file + rename), so a reader never sees half a file. A
worker that misses a map takes ``<map>.lock`` (created exclusively) while it computes it;
another worker that needs the same frame meanwhile waits for the map instead of computing
it again (tasks of one sequence running side by side share the work). A lock older than
``stale_after`` seconds (its worker died) is ignored.

``key`` names the source: the caller derives it from everything that determines the maps
(sequence path, disparity settings, package version), e.g. with :func:`cache_key`.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from vio_core.errors import InputError

from ..frame import Frame
from .base import DisparitySource, missing_disparity_reason

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
        stale_after: seconds after which another worker's lock is ignored.
        poll: seconds between looks while waiting for another worker's map.

    Attributes:
        kind: the wrapped source's kind (a SIMULATED map stays labelled SIMULATED).
        hits, misses: maps read from the cache / computed, since construction.
    """

    def __init__(self, source: DisparitySource, folder, key: str, *, stale_after: float = 600.0, poll: float = 0.05):
        if not key or any(c in key for c in "/\\") or key.startswith("."):
            raise InputError(f"disparity cache key must be a plain file name, got {key!r}")
        self.source = source
        self.kind = source.kind
        self.folder = Path(folder) / key
        self.folder.mkdir(parents=True, exist_ok=True)
        self.stale_after = float(stale_after)
        self.poll = float(poll)
        self.hits = 0
        self.misses = 0

    def path_for(self, frame: Frame) -> Path:
        return self.folder / f"{int(frame.index):06d}_{frame.stem}.npy"

    def missing_reason(self, frame: Frame) -> str:
        """The wrapped source's reason for having no map for ``frame``."""
        return missing_disparity_reason(self.source, frame)

    def _read(self, path: Path, none_marker: Path) -> tuple[bool, np.ndarray | None]:
        """``(found, map)``: the stored map (or None for a stored "no map"), if readable."""
        if none_marker.is_file():
            return True, None
        if path.is_file():
            try:
                return True, np.load(path, allow_pickle=False)
            except (OSError, ValueError):
                return False, None  # a damaged entry is recomputed and replaced
        return False, None

    def _wait_for_other(self, lock: Path, path: Path, none_marker: Path) -> tuple[bool, np.ndarray | None]:
        """Wait while another worker holds ``lock``; ``(found, map)`` once it wrote the map."""
        while True:
            try:
                age = time.time() - lock.stat().st_mtime
            except FileNotFoundError:  # released: the map is there, or the other worker failed
                return self._read(path, none_marker)
            if age > self.stale_after:
                return False, None
            time.sleep(self.poll)
            found, d = self._read(path, none_marker)
            if found:
                return found, d

    def __call__(self, frame: Frame) -> np.ndarray | None:
        path = self.path_for(frame)
        none_marker = path.with_suffix(_NONE_SUFFIX)
        found, d = self._read(path, none_marker)
        if found:
            self.hits += 1
            return d
        lock = path.with_suffix(".lock")
        try:
            os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            owner = True
        except FileExistsError:
            owner = False
            found, d = self._wait_for_other(lock, path, none_marker)
            if found:
                self.hits += 1
                return d
        try:
            self.misses += 1
            d = self.source(frame)
            if d is None:
                _write_atomic(none_marker, lambda fh: None)
            else:
                _write_atomic(path, lambda fh: np.save(fh, d, allow_pickle=False))
            return d
        finally:
            if owner:
                lock.unlink(missing_ok=True)


def _write_atomic(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
