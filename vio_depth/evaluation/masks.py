"""The standard evaluation masks: depth caps and the KITTI crops, named so reports can state them.

An :class:`EvalMask` says which ground-truth pixels are scored: depth within
``[min_depth, max_depth]`` (the caps: 80 m for KITTI / DDAD, 10 m indoors) and, optionally,
inside a crop of the image. The crops are the ones every KITTI Eigen-split evaluation uses
(Monodepth2, Depth Anything, ZoeDepth), as fractions of the image height and width:

* ``garg`` (Garg et al. 2016): rows ``0.40810811 H .. 0.99189189 H``, columns
  ``0.03594771 W .. 0.96405229 W`` -- the standard crop with the 80 m cap;
* ``eigen`` (Eigen et al. 2014): rows ``0.3324324 H .. 0.91351351 H``, same columns.

Pixels are in the crop when ``int(top * H) <= row < int(bottom * H)`` and likewise for
columns (the integer bounds of the published code). :meth:`EvalMask.apply` returns the
ground truth with every pixel outside the crop set to 0 (= not scored); the caps are applied
by :func:`~vio_depth.evaluation.compute_metrics` itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_image
from vio_core.errors import SettingsError, lookup

#: crop name -> (top, bottom, left, right) as fractions of the image height / width
CROPS: dict[str, tuple[float, float, float, float] | None] = {
    "none": None,
    "garg": (0.40810811, 0.99189189, 0.03594771, 0.96405229),
    "eigen": (0.3324324, 0.91351351, 0.03594771, 0.96405229),
}


def crop_bounds(crop: str, height: int, width: int) -> tuple[int, int, int, int] | None:
    """Integer ``(row0, row1, col0, col1)`` (end exclusive) of ``crop`` in an ``height x width`` image, or None."""
    fractions = lookup("evaluation crop", crop, CROPS)
    if fractions is None:
        return None
    top, bottom, left, right = fractions
    return int(top * height), int(bottom * height), int(left * width), int(right * width)


@dataclass(frozen=True)
class EvalMask:
    """Which ground-truth pixels are scored.

    Attributes:
        min_depth: metres, lower cap (> 0).
        max_depth: metres, upper cap (> min_depth): 80 outdoors, 10 indoors.
        crop: a name of :data:`CROPS`.
    """

    min_depth: float = 1e-3
    max_depth: float = 80.0
    crop: str = "none"

    def __post_init__(self):
        if not 0 < self.min_depth < self.max_depth:
            raise SettingsError(f"evaluation caps need 0 < min_depth < max_depth, got "
                                f"[{self.min_depth}, {self.max_depth}]")
        lookup("evaluation crop", self.crop, CROPS)

    def apply(self, gt_depth) -> np.ndarray:
        """``gt_depth: (H, W)`` metres with pixels outside the crop set to 0 (a copy when cropped)."""
        gt = check_image("gt_depth", gt_depth)
        bounds = crop_bounds(self.crop, *gt.shape)
        if bounds is None:
            return gt
        r0, r1, c0, c1 = bounds
        out = np.zeros_like(gt)
        out[r0:r1, c0:c1] = gt[r0:r1, c0:c1]
        return out

    def describe(self) -> str:
        """E.g. ``"depth 0.001-80 m, Garg crop"``."""
        crop = "no crop" if self.crop == "none" else f"{self.crop.capitalize()} crop"
        return f"depth {self.min_depth:g}-{self.max_depth:g} m, {crop}"
