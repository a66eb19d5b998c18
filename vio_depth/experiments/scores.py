"""Per-frame scores of a variant and their aggregation into one row of ``results.csv``.

Every variant produces one :class:`FrameScore` per evaluated frame; :func:`aggregate` turns
them into the row. Conventions, stated once:

* dense metrics (delta1, AbsRel, RMSE, pixel coverage) are :func:`~vio_depth.evaluation.compute_metrics`
  under the entry's :class:`~vio_depth.evaluation.EvalMask`, averaged over the frames that
  got depth (Eigen protocol); frames without depth are not averaged -- ``coverage`` (frames
  with depth / evaluated frames) says how many;
* ``r2``: median over frames with depth of the coefficient of determination of the fit
  used (``1/z`` on ``d`` over its inliers, or over all pixels for the oracle);
* ``points_per_frame``: median over evaluated frames of the points fed to the fit;
  ``point_error``: median over frames of each frame's median ``|z - z_gt| / z_gt`` of those
  points (:func:`~vio_depth.evaluation.point_depth_errors`; not for points sampled from the
  ground truth itself);
* ``seconds_per_frame``: mean wall time per processed frame of the variant's own work
  (disparity excluded: it is the shared input, computed once and cached).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

#: the numeric columns of a row, in ``results.csv`` order
ROW_COLUMNS = ("frames", "frames_with_depth", "coverage", "delta1", "abs_rel", "rmse", "r2", "pixel_coverage",
               "points_per_frame", "point_error", "seconds_per_frame")
#: columns that are timings (differ between runs; everything else must be identical)
TIMING_COLUMNS = ("seconds_per_frame", "seconds")


@dataclass(frozen=True)
class FrameScore:
    """One evaluated frame of one variant (None = not applicable / no depth)."""

    frame: int
    status: str
    has_depth: bool
    delta1: float | None = None
    abs_rel: float | None = None
    rmse: float | None = None
    pixel_coverage: float | None = None
    r2: float | None = None
    points: int | None = None
    point_error: float | None = None

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_json(cls, data: dict) -> "FrameScore":
        return cls(**{k: data.get(k) for k in cls.__dataclass_fields__})


def score_metrics(metrics) -> dict:
    """The :class:`FrameScore` fields of a :class:`~vio_depth.evaluation.DepthMetrics` (None: no pixel)."""
    if metrics is None or metrics.n_pixels == 0:
        return {}
    return {"delta1": metrics.delta1, "abs_rel": metrics.abs_rel, "rmse": metrics.rmse,
            "pixel_coverage": metrics.coverage}


def _values(scores, name: str, depth_only: bool = True) -> list[float]:
    out = []
    for s in scores:
        v = getattr(s, name)
        if (s.has_depth or not depth_only) and v is not None and math.isfinite(v):
            out.append(float(v))
    return out


def aggregate(scores, seconds: float, processed: int) -> dict:
    """The row of ``results.csv`` (see the module docstring) from per-frame scores.

    Args:
        scores: :class:`FrameScore` of every evaluated frame.
        seconds: the variant's own wall time over all processed frames.
        processed: frames processed (>= evaluated for stream variants).
    """
    scores = list(scores)
    scored = [s for s in scores if s.has_depth and s.delta1 is not None]

    def mean(name):
        v = _values(scored, name)
        return float(np.mean(v)) if v else None

    def median(name, depth_only=True):
        v = _values(scores, name, depth_only)
        return float(np.median(v)) if v else None

    n = len(scores)
    with_depth = sum(s.has_depth for s in scores)
    statuses: dict[str, int] = {}
    for s in scores:
        statuses[s.status] = statuses.get(s.status, 0) + 1
    return {
        "frames": n,
        "frames_with_depth": with_depth,
        "coverage": with_depth / n if n else None,
        "delta1": mean("delta1"),
        "abs_rel": mean("abs_rel"),
        "rmse": mean("rmse"),
        "r2": median("r2"),
        "pixel_coverage": mean("pixel_coverage"),
        "points_per_frame": median("points", depth_only=False),
        "point_error": median("point_error", depth_only=False),
        "seconds_per_frame": seconds / processed if processed else None,
        "statuses": dict(sorted(statuses.items())),
    }


def common_frames(score_lists) -> set[int]:
    """Frames that have depth in every list of :class:`FrameScore` (for "on the same frames" tables)."""
    sets = [{s.frame for s in scores if s.has_depth and s.delta1 is not None} for scores in score_lists]
    return set.intersection(*sets) if sets else set()


def mean_on(scores, frames: set[int]) -> dict:
    """delta1 / AbsRel / RMSE averaged over ``frames`` only (None when empty)."""
    chosen = [s for s in scores if s.frame in frames and s.has_depth and s.delta1 is not None]
    if not chosen:
        return {"frames": 0, "delta1": None, "abs_rel": None, "rmse": None}
    return {"frames": len(chosen), **{k: float(np.mean([getattr(s, k) for s in chosen]))
                                      for k in ("delta1", "abs_rel", "rmse")}}
