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
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading

import cv2
import numpy as np

#: libjpeg warnings that mean the decoded pixels are not the file's (jerror.h JWRN_*)
_CORRUPT = re.compile(rb"(Corrupt JPEG data[^\n]*|Premature end of JPEG file[^\n]*|Bogus[^\n]*|"
                      rb"Invalid SOS[^\n]*|Inconsistent progression[^\n]*|JPEG datastream contains no image)")
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


def decode_image_checked(data: bytes, flags: int) -> tuple[np.ndarray | None, str]:
    """``cv2.imdecode`` of encoded image ``data`` with the codec's messages caught.

    JPEG data (by content) first get the structural check of :func:`jpeg_problem`; libjpeg's
    corruption warnings make the image an error. For any format, a failed decode reports
    what the codec printed.

    Returns:
        ``(image, "")`` for a clean decode, else ``(None, problem)`` (the image must not be
        used; ``problem`` is "" only when OpenCV returned nothing and the codec said nothing).
    """
    if not data:
        return None, "empty file"
    jpeg = is_jpeg(data)
    if jpeg:
        problem = jpeg_problem(data)
        if problem:
            return None, problem
    image, text = _decode_watched(np.frombuffer(data, dtype=np.uint8), flags)
    found = _CORRUPT.search(text) if jpeg else None
    said = b" ".join(text.split()).decode("utf-8", "replace")
    if found:
        return None, f"corrupt JPEG data (libjpeg: {found.group(0).decode('ascii', 'replace').strip()})"
    if image is None:
        return None, f"cannot decode image ({said})" if said else "cannot decode image"
    if text.strip():
        os.write(2, text.rstrip(b"\n") + b"\n")  # a warning on a good image: passed on
    return image, ""
