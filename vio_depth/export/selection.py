"""Which frames a report shows: the best, median and worst frame of a run, from its records.

Works on the per-frame JSON records of ``frames.jsonl`` alone, so the run (which writes the
thumbnails) and ``vio-depth report`` (which shows them) pick the same frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: (record key, larger is better, words for the report), tried in this order
CRITERIA = (
    ("abs_rel", False, "AbsRel of the depth map against ground truth"),
    ("points_rel_err_median", False, "median relative error of the triangulated points against ground truth"),
    ("r2", True, "R² of the (alpha, beta) fit"),
    ("inliers", True, "number of inliers of the fit"),
)

STATUSES_WITH_DEPTH = ("ok", "fallback_scale_only", "fallback_previous_fit")


@dataclass(frozen=True)
class FrameSelection:
    """Best, median and worst frame (records of ``frames.jsonl``) by ``criterion``.

    ``frames`` maps "best" / "median" / "worst" to a record; fewer keys when the run has
    fewer than three frames with depth (a frame appears once, under its first label).
    """

    criterion: str
    description: str
    larger_is_better: bool
    frames: dict

    @property
    def stems(self) -> list[str]:
        return [r["stem"] for r in self.frames.values()]


def _value(record: dict, key: str) -> float | None:
    v = record.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


def has_depth(record: dict) -> bool:
    """Whether a frame record says the frame got metric depth."""
    return record.get("status") in STATUSES_WITH_DEPTH


def select_frames(records) -> FrameSelection | None:
    """Best, median and worst of the frames with depth by the first criterion of
    :data:`CRITERIA` that at least half of them carry. None when no frame has depth.

    Ties keep frame order (the earlier frame ranks better).
    """
    frames = [r for r in records if has_depth(r) and "stem" in r]
    if not frames:
        return None
    for key, larger, words in CRITERIA:  # noqa: B007 - the chosen criterion is used after the loop
        scored = [(v, i, r) for i, r in enumerate(frames) if (v := _value(r, key)) is not None]
        if len(scored) * 2 >= len(frames):
            break
    else:
        return None
    scored.sort(key=lambda t: (-t[0] if larger else t[0], t[1]))
    picks = {"best": scored[0][2], "median": scored[(len(scored) - 1) // 2][2], "worst": scored[-1][2]}
    chosen, seen = {}, set()
    for label, rec in picks.items():
        if rec["stem"] not in seen:
            chosen[label] = rec
            seen.add(rec["stem"])
    return FrameSelection(key, words, larger, chosen)
