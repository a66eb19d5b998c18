"""Size limits of untrusted inputs, checked before anything is decoded (one table, issue 23).

A robot log or a downloaded dataset may hold anything: an image header that declares
100000 x 100000 pixels, a ``sequence.json`` nested 100 000 arrays deep, a text file of many
gigabytes. Every reader checks the input's size against these limits *before* decoding it,
so that a bad file ends in one clear error instead of a ``RecursionError`` traceback, an
OpenCV assertion, minutes of decoding or the machine's memory.

Why these values (each far above any real input, far below harm):

* :data:`MAX_IMAGE_PIXELS` 50 megapixels, :data:`MAX_IMAGE_SIDE` 20 000 px: 8K video is
  33 MP (7680 x 4320), the largest machine-vision sensors about 50 MP; a 16000 x 16000
  PNG (256 MP) took 14 s to decode before its size was refused.
* :data:`MAX_TEXT_BYTES` 256 MiB: an IMU at 200 Hz writes about 58 MB of text per hour;
  the limit admits 4 hours in one file (KITTI raw drives hold minutes).
* :data:`MAX_JSON_BYTES` 64 MiB: ``sequence.json``, ``metrics.json`` and the evaluation
  cache are kilobytes to a few megabytes; :data:`MAX_CONFIG_BYTES` 1 MiB for a TOML
  settings file (the complete ``vio-depth config --dump`` is 3 KB).
* :data:`MAX_NESTING` 64 levels of arrays / objects / tables: the deepest document
  vio-depth reads or writes nests 5 levels.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np

#: decoded pixels (width x height) of one image
MAX_IMAGE_PIXELS = 50_000_000
#: width or height of one image, pixels
MAX_IMAGE_SIDE = 20_000
#: bytes of one line-based text file (frame lists, trajectories, IMU samples, frames.jsonl)
MAX_TEXT_BYTES = 256 << 20
#: bytes of one JSON document (sequence.json, metrics.json, eval.json, cache entries)
MAX_JSON_BYTES = 64 << 20
#: bytes of a TOML settings file (``--config``)
MAX_CONFIG_BYTES = 1 << 20
#: nesting depth of arrays / objects (JSON) or arrays / inline tables / tables (TOML)
MAX_NESTING = 64

_JSON_STRINGS = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_TOML_STRINGS = re.compile(rb'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*')


def read_limited(path, limit: int) -> tuple[bytes | None, int]:
    """``(data, size)`` of the file ``path``: ``data`` is None when it holds more than
    ``limit`` bytes (then ``size`` is its size, and at most ``limit + 1`` bytes were read).

    Raises:
        OSError: the file cannot be opened or read.
    """
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > limit:
            return None, size
        data = fh.read(limit + 1)  # the file may grow while it is read
    return (None, len(data)) if len(data) > limit else (data, len(data))


def too_large(size: int, limit: int, what: str) -> str:
    """The message for a ``what`` of ``size`` bytes beyond ``limit``."""
    return f"{what} of {_human(size)} is larger than the {_human(limit)} vio-depth reads (vio_core/limits.py)"


def _human(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def nesting_depth(data: bytes | str, kind: str = "json") -> int:
    """Largest nesting of ``[``/``{`` in a JSON or TOML document (strings and, for TOML,
    comments left out), without parsing it. An unterminated string counts the brackets
    after it (an overestimate, never an underestimate on a document that parses)."""
    if isinstance(data, str):
        data = data.encode("utf-8", "surrogatepass")
    if kind not in ("json", "toml"):
        raise ValueError(f"kind must be 'json' or 'toml', got {kind!r}")
    bare = (_JSON_STRINGS if kind == "json" else _TOML_STRINGS).sub(b"", data)
    b = np.frombuffer(bare, dtype=np.uint8)
    step = (b == ord("[")).astype(np.int32) + (b == ord("{")) - (b == ord("]")) - (b == ord("}"))
    return int(np.cumsum(step).max(initial=0))


def value_depth(value) -> int:
    """Nesting depth of a parsed value (dicts and lists count one level each), computed
    without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        elif not isinstance(v, list):
            deepest = max(deepest, d)
            continue
        deepest = max(deepest, d + 1)
        if d + 1 > MAX_NESTING:
            return d + 1
        stack.extend((x, d + 1) for x in v)
    return deepest


class LimitError(ValueError):
    """An input beyond one of the limits above (a ``ValueError``, like a JSON syntax error,
    so that readers answer both the same way)."""


def parse_json(data: bytes | str):
    """``json.loads(data)`` after checking the nesting depth against :data:`MAX_NESTING`.

    Raises:
        LimitError: nested too deeply. ValueError: not JSON (``json.JSONDecodeError``) or
            not UTF-8 (``UnicodeDecodeError``).
    """
    depth = nesting_depth(data, "json")
    if depth > MAX_NESTING:
        raise LimitError(f"nested {depth} levels deep, more than the {MAX_NESTING} vio-depth reads")
    try:
        return json.loads(data)
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise LimitError(f"nested more than the {MAX_NESTING} levels vio-depth reads") from None


def read_json_file(path, limit: int = MAX_JSON_BYTES, what: str = "JSON file"):
    """The parsed JSON document in ``path``, its size and nesting checked first.

    Raises:
        OSError: cannot be read. LimitError: larger than ``limit`` bytes or nested too
            deeply. ValueError: not JSON or not UTF-8.
    """
    data, size = read_limited(path, limit)
    if data is None:
        raise LimitError(too_large(size, limit, what))
    return parse_json(data)


def image_size_problem(width: int, height: int, what: str = "image") -> str:
    """Why an image of ``width`` x ``height`` pixels is refused ("" when it is not)."""
    if width <= 0 or height <= 0:
        return f"{what} header declares {width}x{height} pixels"
    if max(width, height) > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS:
        return (f"{what} header declares {width}x{height} pixels, more than vio-depth decodes "
                f"(at most {MAX_IMAGE_SIDE} px a side and {MAX_IMAGE_PIXELS / 1e6:.0f} megapixels)")
    return ""


__all__ = [
    "MAX_CONFIG_BYTES", "MAX_IMAGE_PIXELS", "MAX_IMAGE_SIDE", "MAX_JSON_BYTES", "MAX_NESTING", "MAX_TEXT_BYTES",
    "LimitError", "image_size_problem", "nesting_depth", "parse_json", "read_json_file", "read_limited",
    "too_large", "value_depth",
]
