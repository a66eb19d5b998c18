"""Image decoding that turns the codec's messages into errors (never a silently wrong frame).

libjpeg treats damaged entropy-coded data as *recoverable*: it prints a warning such as
"Corrupt JPEG data: premature end of data segment" on the process's standard error, fills
what it could not decode and returns an image; OpenCV's ``imdecode`` neither exposes the
warning nor fails. Such a frame would enter the pipeline with a smeared or grey region.

How it is caught (the choice, and why):

* A **structural check** in Python first (:func:`jpeg_problem`): SOI at the start, the
  marker segments up to the first SOS with consistent lengths, and the EOI marker at the
  end (a truncated file). Cheap and exact, but blind to damage inside the compressed data.
* Damage inside the compressed data can only be seen by decoding it (a Huffman decode);
  a pure-Python decoder would be hundreds of times slower than libjpeg. So the decode
  itself is watched: for the duration of ``cv2.imdecode`` the file descriptor 2 is
  pointed at an in-memory file (``memfd``), and any libjpeg message about corrupt or
  premature data makes the image an error naming the file. Other text written there
  (none is expected) is passed on to the real stderr. Decodes are serialised by a lock,
  because fd 2 belongs to the whole process; another thread writing to stderr during a
  decode (milliseconds) would have its text passed on after it.

Not detectable by any decoder: a corruption that still decodes as valid compressed data
(a flipped bit that yields another valid Huffman code). Only a checksum from the producer
could catch that.

Other formats (PNG) are decoded the same way, watched: libpng prints its errors ("libpng
error: IDAT: incorrect data check") on stderr before OpenCV returns nothing; the message
becomes part of the one-line error instead of a second line on stderr. (PNG carries CRCs,
so a damaged PNG fails to decode rather than decoding wrongly.)

**Size before decoding** (issue 23). The width and height are read from the PNG (IHDR)
or JPEG (SOF) header and checked against :func:`vio_core.limits.image_size_problem` and,
where the caller knows it, the camera's size, before a single pixel is decoded: a header
declaring 100000 x 100000 pixels raised an OpenCV assertion, a real 16000 x 16000 PNG took
14 s to decode before its size was refused. Other formats (BMP, TIFF, WebP...) are decoded
under OpenCV's own limit (2^30 pixels) and checked after decoding.

**Warnings as errors.** Every message libjpeg prints while decoding a JPEG makes the
image corrupt (not only "Corrupt JPEG data"; e.g. "unknown JFIF revision number 132.01" is
a damaged header). A JPEG written with restart markers (``DRI``) is checked interval by
interval by libjpeg: damage inside the compressed data shifts the bit count of its interval
and the decoder meets the next ``RST`` marker early ("premature end of data segment") or
late ("N extraneous bytes before marker"). Measured on 10 sample JPEGs x 60 damages each
(96 random bytes written over the compressed data, ``tests/robustness``): with a restart
marker every MCU 0 of 600 damages went undetected, every 4 MCUs 13, every 16 MCUs 34,
**without restart markers 44 of 600 (7 %)**: the Huffman code resynchronises after the
damage and the whole scan still has the right length, so the image decodes with a damaged
band and no decoder can tell. Those stay undetectable (docs/safety.md).

OpenCV's own log lines (``[ WARN:0@1.23] global grfmt_png.cpp:793 readFromStreamOrBuffer
...``) are reduced to their message before they become part of an error.
"""

from __future__ import annotations

import logging
import os
import re
import struct
import sys
import tempfile
import threading

import cv2
import numpy as np

from vio_core.errors import CorruptImageError, SequenceFormatError
from vio_core.limits import image_size_problem

log = logging.getLogger(__name__)

#: libjpeg warnings that mean the decoded pixels are not the file's (jerror.h JWRN_*)
_CORRUPT = re.compile(rb"(Corrupt JPEG data[^\n]*|Premature end of JPEG file[^\n]*|Bogus[^\n]*|"
                      rb"Invalid SOS[^\n]*|Inconsistent progression[^\n]*|JPEG datastream contains no image)")
#: an OpenCV log line's prefix: ``[ WARN:0@0.583] global grfmt_png.cpp:793 readFromStreamOrBuffer ``
_OPENCV_LOG = re.compile(rb"\[\s*(?:WARN|ERROR|INFO|DEBUG|VERBOSE|FATAL)\s*:\d+@[\d.]+\]\s*(?:global\s+)?"
                         rb"(?:\S+\.(?:cpp|hpp|h|c):\d+\s+)?(?:[A-Za-z_][\w:]*\s+)?")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (FF C0-CF without DHT C4, JPG C8, DAC CC)
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_LOCK = threading.Lock()
_SINK: int | None = None


def is_jpeg(data: bytes) -> bool:
    """True when ``data`` starts with the JPEG SOI marker (FF D8 FF)."""
    return data[:3] == b"\xff\xd8\xff"


def jpeg_problem(data: bytes) -> str:
    """A structural problem of JPEG ``data`` ("" when none is found).

    Checks the markers from SOI to the first SOS (each segment's length must fit in the
    file) and the EOI marker FF D9 at the end (trailing zero padding allowed).
    """
    n = len(data)
    if not is_jpeg(data):
        return "not a JPEG (no SOI marker)"
    i = 2
    while True:
        if i >= n:
            return "truncated JPEG (ends inside its headers)"
        if data[i] != 0xFF:
            return f"corrupt JPEG (no marker at byte {i} of its headers)"
        while i < n and data[i] == 0xFF:  # fill bytes
            i += 1
        if i >= n:
            return "truncated JPEG (ends inside its headers)"
        marker = data[i]
        i += 1
        if marker == 0xD9:
            return "JPEG without image data (EOI before SOS)"
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue  # no length field
        if i + 2 > n:
            return "truncated JPEG (ends inside a marker segment)"
        length = (data[i] << 8) | data[i + 1]
        if length < 2 or i + length > n:
            return f"corrupt JPEG (marker FF {marker:02X} segment of {length} bytes does not fit the file)"
        if marker == 0xDA:  # SOS: entropy-coded data follow
            break
        i += length
    if not _has_end(data):
        return "truncated JPEG (no end-of-image marker)"
    return ""


def _has_end(data: bytes) -> bool:
    tail = np.frombuffer(data[-64:], dtype=np.uint8)
    nz = np.flatnonzero(tail)
    return len(nz) >= 2 and tail[nz[-1]] == 0xD9 and tail[nz[-1] - 1] == 0xFF


def _sink() -> int:
    global _SINK
    if _SINK is None:
        try:
            _SINK = os.memfd_create("vio-depth-libjpeg", os.MFD_CLOEXEC)
        except (AttributeError, OSError):
            _SINK = os.dup(tempfile.TemporaryFile().fileno())
    return _SINK


def _decode_watched(buf: np.ndarray, flags: int) -> tuple[np.ndarray | None, bytes]:
    """``cv2.imdecode(buf, flags)`` and what the codec wrote to fd 2 meanwhile."""
    with _LOCK:
        sink = _sink()
        os.lseek(sink, 0, os.SEEK_SET)
        os.ftruncate(sink, 0)
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (AttributeError, ValueError, OSError):
                pass
        saved = os.dup(2)
        try:
            os.dup2(sink, 2)
            image = cv2.imdecode(buf, flags)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        size = os.lseek(sink, 0, os.SEEK_CUR)
        os.lseek(sink, 0, os.SEEK_SET)
        text = os.read(sink, size) if size else b""
    return image, text


def image_dimensions(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` declared by a PNG (IHDR) or JPEG (SOF) header, read without
    decoding; None for other formats or a header too damaged to say."""
    if data[:8] == _PNG_SIGNATURE:
        if len(data) < 24 or data[12:16] != b"IHDR":
            return None
        return struct.unpack(">II", data[16:24])
    if not is_jpeg(data):
        return None
    i, n = 2, len(data)
    while i + 4 <= n and data[i] == 0xFF:
        while i < n and data[i] == 0xFF:
            i += 1
        if i + 3 > n:
            return None
        marker = data[i]
        i += 1
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue
        if marker in (0xD9, 0xDA):
            return None
        length = (data[i] << 8) | data[i + 1]
        if marker in _SOF:
            if i + 7 > n:
                return None
            height, width = struct.unpack(">HH", data[i + 3:i + 7])
            return width, height
        i += length
    return None


def opencv_message(text: bytes) -> str:
    """What the codecs printed, one line, OpenCV's log prefixes removed."""
    return " ".join(_OPENCV_LOG.sub(b"", text).decode("utf-8", "replace").split())


class CorruptData(str):
    """A decode problem that means damaged compressed data (libjpeg complained), as
    opposed to a file that cannot be an image at all."""


def decode_image_checked(data: bytes, flags: int,
                         expected_size: tuple[int, int] | None = None) -> tuple[np.ndarray | None, str]:
    """``cv2.imdecode`` of encoded image ``data`` with the size checked first and the codec's
    messages caught.

    PNG and JPEG headers are read first (:func:`image_dimensions`): a size beyond
    :mod:`vio_core.limits` or other than ``expected_size`` ``(width, height)`` is refused
    without decoding. JPEG data (by content) get the structural check of
    :func:`jpeg_problem`; every libjpeg message makes the image corrupt. For any format, a
    failed decode reports what the codec printed (OpenCV's log prefixes removed).

    Returns:
        ``(image, "")`` for a clean decode, else ``(None, problem)`` (the image must not be
        used; ``problem`` is "" only when OpenCV returned nothing and the codec said nothing).
        ``problem`` is a :class:`CorruptData` when the data are damaged inside.
    """
    if not data:
        return None, "empty file"
    dims = image_dimensions(data)
    if dims is not None:
        problem = image_size_problem(*dims)
        if problem:
            return None, problem
        if expected_size is not None and tuple(dims) != tuple(expected_size):
            return None, (f"image is {dims[0]}x{dims[1]} but the camera is {expected_size[0]}x{expected_size[1]} "
                          "(read from its header)")
    jpeg = is_jpeg(data)
    if jpeg:
        problem = jpeg_problem(data)
        if problem:
            return None, problem
    try:
        image, text = _decode_watched(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error as exc:  # OpenCV's own checks (its 2^30 pixel limit for formats read here unchecked)
        return None, f"cannot decode image ({opencv_message(str(exc).encode())})"
    said = opencv_message(text)
    if jpeg and said:
        found = _CORRUPT.search(text)
        what = found.group(0).decode("ascii", "replace").strip() if found else said
        return None, CorruptData(f"corrupt JPEG data (libjpeg: {what})")
    if image is None:
        return None, f"cannot decode image ({said})" if said else "cannot decode image"
    if said:
        log.warning("image decoder: %s", said)  # a warning on a good (non-JPEG) image: passed on
    return image, ""


def decode_image(data: bytes, flags: int, path, *, what: str = "",
                 expected_size: tuple[int, int] | None = None) -> np.ndarray:
    """:func:`decode_image_checked`, its problems raised naming ``path``.

    Raises:
        CorruptImageError: damaged compressed data (a JPEG libjpeg complained about).
        SequenceFormatError: anything else (empty, truncated, undecodable, too large, other
            than ``expected_size``).
    """
    image, problem = decode_image_checked(data, flags, expected_size)
    if image is None:
        text = f"{what}: {problem}" if what else problem
        if isinstance(problem, CorruptData):
            raise CorruptImageError(path, text)
        raise SequenceFormatError(path, text)
    return image
