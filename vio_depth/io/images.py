"""Reading images: bytes are read by Python and decoded by OpenCV (safe for any path: OpenCV's own
path handling crashed on bytes that are not UTF-8), JPEGs with libjpeg's warnings as errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.errors import SequenceFormatError

from .decode import decode_image


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

    JPEG data (recognised by content, whatever the file name) are decoded with libjpeg's
    corruption warnings turned into errors (:mod:`vio_depth.io.decode`).

    The size is read from the PNG / JPEG header and checked (limits, ``camera``'s size)
    before decoding.

    Raises:
        CorruptImageError: damaged compressed data (libjpeg complained): a run gives the
            frame the status ``corrupt_image``.
        SequenceFormatError: missing/unreadable/undecodable file, a truncated JPEG, a size
            beyond the limits or other than ``camera``'s.
    """
    path = Path(path)
    data = read_image_bytes(path)
    expected = None if camera is None else (camera.width, camera.height)
    image = decode_image(data, cv2.IMREAD_COLOR_RGB, path, expected_size=expected)
    if camera is not None and image.shape[:2] != (camera.height, camera.width):
        raise SequenceFormatError(
            path, f"image is {image.shape[1]}x{image.shape[0]} but the camera is {camera.width}x{camera.height}")
    return image
