"""The "model" disparity kind: a Depth Anything network (:mod:`vio_depth.models`) run on each image."""

from __future__ import annotations

import numpy as np

from ..frame import Frame
from ..models import DepthAnythingArchitecture, DepthAnythingModel, DepthAnythingSettings, load_depth_anything
from .base import DisparityKind, check_disparity


class ModelDisparity:
    """Disparity source running a Depth Anything network on each frame's image.

    ``ModelDisparity(model)(frame)`` is ``model.predict(frame.image())``, checked to be
    (H, W) like the frame's camera. ``kind`` is MODEL (written to frames.jsonl).
    """

    kind = DisparityKind.MODEL

    def __init__(self, model: DepthAnythingModel):
        self.model = model

    @classmethod
    def from_path(cls, path, settings: DepthAnythingSettings | None = None, *,
                  variant: str | DepthAnythingArchitecture | None = None) -> "ModelDisparity":
        """Load weights with :func:`load_depth_anything` and wrap them."""
        return cls(load_depth_anything(path, settings, variant=variant))

    def __repr__(self) -> str:
        return f"ModelDisparity({self.model!r})"

    def __call__(self, frame: Frame) -> np.ndarray:
        disparity = self.model.predict(frame.image())
        return check_disparity(disparity, frame, f"{self.model.path} on frame {frame.stem}")
