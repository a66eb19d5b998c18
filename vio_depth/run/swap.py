"""Moving a finished run into place: an atomic swap of two folders (issue 12), deleting only
what was checked (issue 23).

``replace_folder(new, target, marker_id)`` puts the folder ``new`` where ``target`` is. With
``target`` present, the two are exchanged atomically where the OS can (Linux
``renameat2(RENAME_EXCHANGE)``), else ``target`` is renamed aside first
(``.<name>.vio-depth-old``). The old content is deleted only when it is still what the
caller checked before the run: an empty folder, or the run whose marker
(:mod:`vio_depth.io.marker`) carries ``marker_id``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import logging
import os
import shutil
from pathlib import Path

from ..io.marker import read_marker

log = logging.getLogger(__name__)

#: suffix of the old content of ``--out`` during a two-rename swap (systems without renameat2)
ASIDE_SUFFIX = ".vio-depth-old"


def aside_path(out) -> Path:
    """Where the old content of ``out`` is moved during a swap on systems without an atomic
    exchange: ``.<name>.vio-depth-old`` in the same parent."""
    out = Path(os.path.abspath(out))
    return out.parent / f".{out.name[:200]}{ASIDE_SUFFIX}"


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two paths (Linux renameat2 RENAME_EXCHANGE); False when unsupported."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _remove_replaced(old: Path, marker_id: str | None) -> bool:
    """Delete ``old`` (the former content of ``--out``) when it is what was checked before
    the swap: an empty folder (``marker_id`` None) or a run carrying the marker id
    ``marker_id``. Returns False (nothing deleted) otherwise."""
    if marker_id is None:
        try:
            os.rmdir(old)
            return True
        except OSError:
            return False
    if read_marker(old, "run") != marker_id:
        return False
    shutil.rmtree(old, ignore_errors=True)
    return True


def replace_folder(new: Path, target: Path, marker_id: str | None = None) -> None:
    """Move the folder ``new`` to ``target``, replacing ``target`` (a folder) when it exists.

    With ``target`` present, the two are exchanged atomically where the OS can (Linux), else
    ``target`` is renamed aside first. The old content is deleted afterwards only when it is
    still what the caller checked: an empty folder (``marker_id`` None) or the run whose
    marker carries ``marker_id``. Anything else (a folder put there during the run) is
    swapped back and ``OSError(EBUSY)`` raised: nothing is replaced.
    """
    if not os.path.lexists(target):
        os.rename(new, target)
        return
    if _exchange(new, target):
        if not _remove_replaced(new, marker_id):  # ``new`` now holds the old content
            _exchange(new, target)
            raise OSError(errno.EBUSY, "it changed while the run was working (it no longer holds what was checked "
                                       f"at the start); nothing was replaced, the result is in {new}", str(target))
        return
    aside = aside_path(target)
    if os.path.lexists(aside):
        if read_marker(aside, "run") is None:
            raise OSError(errno.EEXIST, "exists and carries no vio-depth marker; vio-depth never deletes it (move it "
                                        "away)", str(aside))
        shutil.rmtree(aside)
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except OSError:
        os.rename(aside, target)
        raise
    if not _remove_replaced(aside, marker_id):
        log.warning("%s: the former content of %s changed during the run; kept there, not deleted", aside, target)


__all__ = ["ASIDE_SUFFIX", "aside_path", "replace_folder"]
