"""Depth Anything's own image preprocessing and output upsampling, in plain numpy/OpenCV.

These reproduce the official ``DepthAnythingV2.image2tensor`` / ``infer_image`` (the
MiDaS-style ``Resize`` transform with ``keep_aspect_ratio=True, ensure_multiple_of=14,
resize_method="lower_bound"``, ``cv2.INTER_CUBIC``, ImageNet normalisation) so that the
same numbers reach the network whatever runs it (torch or onnxruntime):

* :func:`network_input_size` -- the (h, w) the network sees for an H x W image;
* :func:`preprocess_image` -- uint8 RGB image -> (1, 3, h, w) float32 network input;
* :func:`resize_disparity` -- network output (h, w) -> (H, W) bilinear upsampling
  (``align_corners=True`` as the official V2 ``infer_image``).

Only numpy and OpenCV are needed here (no torch).
"""

from __future__ import annotations

import cv2
import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, ShapeError

#: DINOv2 patch size: every network input side is a multiple of this
PATCH_SIZE = 14
#: ImageNet mean / std of RGB in [0, 1] (Depth Anything's NormalizeImage)
IMAGENET_MEAN = np.array([0.485, 0.456, 0.406])
IMAGENET_STD = np.array([0.229, 0.224, 0.225])


def network_input_size(height: int, width: int, input_size: int = 518,
                       multiple: int = PATCH_SIZE) -> tuple[int, int]:
    """(h, w) pixels of the network input for an image of ``height`` x ``width`` pixels.

    The official "lower bound" policy (``Resize(width=input_size, height=input_size,
    keep_aspect_ratio=True, ensure_multiple_of=14, resize_method="lower_bound")``):

    1. one scale for both sides, ``s = max(input_size / height, input_size / width)``,
       so the *shorter* side becomes ``input_size`` and the aspect ratio is kept (images
       smaller than ``input_size`` are enlarged);
    2. each scaled side is rounded to the nearest multiple of ``multiple`` (numpy's
       round-half-to-even), and rounded *up* instead when that would fall below
       ``input_size``.

    Both returned sides are therefore multiples of ``multiple`` and at least
    ``input_size`` (when ``input_size`` is itself a multiple, the shorter side equals it).
    Example: KITTI 375 x 1242 -> 518 x 1722; 480 x 640 -> 518 x 686.

    Note: transformers' ``DPTImageProcessor`` "scales as little as possible" instead, which
    gives the same size whenever the image is larger than ``input_size`` on both sides
    but a smaller one for images smaller than ``input_size``; vio-depth follows the
    official code.
    """
    if height <= 0 or width <= 0:
        raise ShapeError(f"image size must be positive, got {height} x {width}")
    if input_size < multiple or multiple <= 0:
        raise InputError(f"input_size must be at least {multiple}, got {input_size}")
    scale = max(input_size / height, input_size / width)

    def constrain(x: float) -> int:
        y = int(np.round(x / multiple) * multiple)
        if y < input_size:
            y = int(np.ceil(x / multiple) * multiple)
        return y

    return constrain(scale * height), constrain(scale * width)


def preprocess_image(image, input_size: int = 518, size: tuple[int, int] | None = None) -> np.ndarray:
    """Network input for ``image: (H, W, 3) uint8 RGB``: ``(1, 3, h, w)`` float32.

    ``image / 255`` (float64, as the official code), bicubic resize (``cv2.INTER_CUBIC``)
    to ``size = (h, w)`` pixels -- by default :func:`network_input_size` of the image --
    then ``(x - mean) / std`` per channel with the ImageNet statistics, channels first.
    Pass ``size`` for a network with a fixed input size (the image is then stretched to
    exactly that size, as the fixed-size ONNX exports expect).

    Raises:
        ShapeError: not an (H, W, 3) uint8 image.
    """
    img = check_image("image", image, channels=3)
    if img.dtype != np.uint8:
        raise ShapeError(f"image: expected uint8 RGB values, got dtype {img.dtype}")
    if size is None:
        size = network_input_size(img.shape[0], img.shape[1], input_size)
    h, w = int(size[0]), int(size[1])
    if h <= 0 or w <= 0:
        raise ShapeError(f"size: network input size must be positive, got {size}")
    x = img.astype(np.float64) / 255.0
    if (h, w) != x.shape[:2]:
        x = cv2.resize(x, (w, h), interpolation=cv2.INTER_CUBIC)
    x = (x - IMAGENET_MEAN) / IMAGENET_STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)


def _linear_taps(n_in: int, n_out: int, align_corners: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source indices i0, i1 (n_out,) and weights of i1 (n_out,) for 1-D linear resampling.

    Same sampling positions as ``torch.nn.functional.interpolate(mode="bilinear")``.
    """
    out = np.arange(n_out, dtype=np.float64)
    if align_corners:
        src = out * ((n_in - 1) / (n_out - 1)) if n_out > 1 else np.zeros(n_out)
    else:
        src = np.maximum((out + 0.5) * (n_in / n_out) - 0.5, 0.0)
    i0 = np.minimum(np.floor(src).astype(np.int64), n_in - 1)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, src - i0


def resize_disparity(disparity, height: int, width: int, *, align_corners: bool = True) -> np.ndarray:
    """Bilinear resampling of ``disparity: (h, w)`` to ``(height, width)`` float32.

    Matches ``F.interpolate(d[None, None], (height, width), mode="bilinear",
    align_corners=align_corners)``: the official Depth Anything V2 ``infer_image`` uses
    ``align_corners=True`` (V1's ``run.py`` used ``False``). Values are resampled as they
    are (no clipping, no absolute value).
    """
    d = check_array("disparity", disparity, (None, None))
    if height <= 0 or width <= 0:
        raise ShapeError(f"output size must be positive, got {height} x {width}")
    h, w = d.shape
    if (h, w) == (height, width):
        return d.astype(np.float32, copy=True)
    r0, r1, wr = _linear_taps(h, height, align_corners)
    c0, c1, wc = _linear_taps(w, width, align_corners)
    d = d.astype(np.float64, copy=False)
    rows = d[r0] * (1.0 - wr)[:, None] + d[r1] * wr[:, None]
    out = rows[:, c0] * (1.0 - wc)[None, :] + rows[:, c1] * wc[None, :]
    return out.astype(np.float32)
