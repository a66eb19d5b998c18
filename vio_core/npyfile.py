"""Reading ``.npy`` / ``.npz`` arrays from untrusted files: one clear error, never a traceback.

``numpy.load`` fails in many ways on a damaged file (``EOFError`` on an empty file,
``ValueError`` on a bad header, ``zipfile.BadZipFile``, ``KeyError``, ``MemoryError`` when
a header declares a huge shape) and never runs pickled code here (``allow_pickle=False``).
:func:`load_array` checks a ``.npy`` header against the file size before reading, and turns
every failure into :class:`~vio_core.errors.InputError` naming the file.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .errors import InputError


def _npy_size_problem(path: Path) -> str:
    """Why the ``.npy`` header of ``path`` cannot match its size ("" when it can)."""
    fmt = np.lib.format
    with open(path, "rb") as fh:
        major, _ = fmt.read_magic(fh)
        if major == 1:
            shape, _, dtype = fmt.read_array_header_1_0(fh)
        else:
            shape, _, dtype = fmt.read_array_header_2_0(fh)
        header = fh.tell()
    if dtype.hasobject:
        return "holds Python objects (pickles are never loaded)"
    need = math.prod(shape) * dtype.itemsize
    have = path.stat().st_size - header
    if need != have:
        return f"header declares {shape} {dtype} ({need} bytes) but the file holds {have} bytes of data"
    return ""


def load_array(path, what: str = "array", key: str | None = None) -> np.ndarray:
    """The array in ``path`` (``.npy``; or member ``key`` of a ``.npz``).

    Raises:
        InputError: missing, unreadable or damaged file, a missing ``key``, a size that does
            not match the header, or an object array (the message names the file and ``what``).
    """
    path = Path(path)
    try:
        if key is None:
            problem = _npy_size_problem(path)
            if problem:
                raise InputError(f"{path}: cannot read {what}: {problem}")
            return np.load(path, allow_pickle=False)
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise InputError(f"{path}: cannot read {what}: not a .npz archive")
        with loaded as z:
            if key not in z.files:
                raise InputError(f"{path}: cannot read {what}: expected key {key!r}, found {z.files}")
            return np.asarray(z[key])
    except InputError:
        raise
    except (Exception, MemoryError) as exc:  # noqa: BLE001  numpy's failures on damaged files are open-ended
        # (EOFError, ValueError, SyntaxError, tokenize.TokenError, zipfile.BadZipFile, KeyError,
        # MemoryError, ...): for an untrusted file every one of them means "cannot read it"
        raise InputError(f"{path}: cannot read {what} ({type(exc).__name__}: {exc})"[:400]) from None
