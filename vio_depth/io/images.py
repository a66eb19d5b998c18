"""Reading images: bytes are read by Python and decoded by OpenCV (safe for any path)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.errors import SequenceFormatError


def read_image_bytes(path) -> bytes:
    """The file's bytes, or :class:`SequenceFormatError` when it is missing or unreadable.

    Python opens the file (OpenCV's own path handling crashes on some byte sequences).
    """
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise SequenceFormatError(path, "image file not found") from None
    except IsADirectoryError:
        raise SequenceFormatError(path, "is a folder, not an image file") from None
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read image: {exc.strerror or exc}") from None


def read_rgb_image(path, camera: Camera | None = None) -> np.ndarray:
    """Read an image file as ``(H, W, 3)`` uint8 RGB (grey images are expanded to 3 channels).

    Raises:
        SequenceFormatError: missing/unreadable/undecodable file, a truncated JPEG, or a size
            that differs from ``camera``'s.
    """
    path = Path(path)
    data = read_image_bytes(path)
    if path.suffix.lower() in (".jpg", ".jpeg") and not has_jpeg_end(data):
        # checked here: libjpeg would print its own warning and decode a grey-filled image
        raise SequenceFormatError(path, "truncated JPEG (no end-of-image marker)")
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR_RGB) if data else None
    if image is None:
        raise SequenceFormatError(path, "cannot decode image")
    if camera is not None and image.shape[:2] != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"image is {image.shape[1]}x{image.shape[0]} but the camera is {camera.width}x{camera.height}")
    return image


def has_jpeg_end(data: bytes) -> bool:
    """True when JPEG ``data`` ends with the EOI marker FF D9 (trailing zero padding allowed)."""
    tail = np.frombuffer(data[-64:], dtype=np.uint8)
    nz = np.flatnonzero(tail)
    return len(nz) >= 2 and tail[nz[-1]] == 0xD9 and tail[nz[-1] - 1] == 0xFF
