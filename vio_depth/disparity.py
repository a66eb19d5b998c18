"""Where each frame's affine-invariant disparity comes from.

* :class:`SequenceDisparity` -- the sequence's own disparity (for the bundled samples a
  *simulated* affine-invariant disparity generated from ground truth at load time).
* :class:`DisparityDirectory` -- ``DIR/<image file stem>.npy`` files (float32, H x W),
  e.g. predictions of Depth Anything written by another tool.

A source is a callable ``source(frame) -> (H, W) float32 disparity | None``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from vio_core.errors import InputError
from .types import Frame


class DisparitySource(Protocol):
    #: "simulated", "file" or "model": written to frames.jsonl and metrics.json
    kind: str

    def __call__(self, frame: Frame) -> np.ndarray | None: ...


def check_disparity(disparity, frame: Frame, origin: str) -> np.ndarray:
    """Validate a disparity map for ``frame``: (H, W) matching the camera, float, finite or NaN.

    Raises:
        InputError: wrong shape or dtype (the message names ``origin``).
    """
    d = np.asarray(disparity)
    cam = frame.camera
    if d.ndim != 2 or d.shape != (cam.height, cam.width):
        raise InputError(
            f"{origin}: disparity must be ({cam.height}, {cam.width}) to match the image, got {d.shape}"
        )
    if d.dtype.kind != "f":
        raise InputError(f"{origin}: disparity must be a float array, got dtype {d.dtype}")
    if np.isinf(d).any():
        raise InputError(f"{origin}: disparity contains infinite values")
    return d.astype(np.float32, copy=False)


class SequenceDisparity:
    """The sequence's own disparity maps (``Frame.disparity()``)."""

    def __init__(self, sequence):
        self.kind = "simulated" if getattr(sequence, "disparity_is_simulated", False) else "file"
        if not sequence.has_disparity:
            raise InputError(
                f"{sequence.root}: the sequence carries no disparity maps; pass --disparity DIR "
                "with one <image stem>.npy per frame"
            )

    def __call__(self, frame: Frame) -> np.ndarray | None:
        d = frame.disparity()
        return None if d is None else check_disparity(d, frame, f"disparity of frame {frame.stem}")


class DisparityDirectory:
    """``DIR/<image file stem>.npy`` per frame (float32, H x W affine-invariant disparity)."""

    kind = "file"

    def __init__(self, directory):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise InputError(f"{self.directory}: disparity folder does not exist")

    def path_for(self, frame: Frame) -> Path:
        return self.directory / f"{frame.stem}.npy"

    def __call__(self, frame: Frame) -> np.ndarray | None:
        path = self.path_for(frame)
        if not path.is_file():
            return None  # reported as status no_disparity for this frame
        try:
            d = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read disparity ({exc})") from None
        return check_disparity(d, frame, str(path))
