"""The per-stage timings of a run, summarised for ``metrics.json`` (``timings``).

Every frame record carries ``timings``: seconds per stage, wherever the stage ran
(docs/frames_schema.md). With overlap (:mod:`vio_depth.run.overlap`) the stages of
different frames run at the same time in three lanes, so the run's wall time is not their
sum: ``frames_per_second`` is measured on the wall clock, and ``lanes`` gives each lane's
total busy time, whose largest is the lane that bounds the run on enough cores.
"""

from __future__ import annotations

import numpy as np

#: stages in the order of a frame's way through the run (``matching`` and ``triangulation``
#: are parts of ``points``)
STAGES = ("load", "image", "features", "disparity", "points", "matching", "triangulation", "fit", "depth", "write",
          "evaluation")
#: which lane each stage runs in (docs: :mod:`vio_depth.run.overlap`)
LANES = {"prefetch": ("load", "image", "features", "disparity"), "pipeline": ("points", "fit", "depth"),
         "writer": ("write", "evaluation")}


def timing_summary(frame_timings: list[dict], wall_s: float, *, overlap: bool, backfill_s: float = 0.0,
                   prefetch_workers: int = 1) -> dict:
    """The ``timings`` block of ``metrics.json``.

    Args:
        frame_timings: one ``{stage: seconds}`` per processed frame (the records' ``timings``).
        wall_s: seconds, the whole run's wall time (from the first frame to the last output).
        overlap: whether the stages overlapped in worker threads.
        prefetch_workers: threads of the prefetch lane.
        backfill_s: seconds of wall time spent in the offline backward pass (its frames that
            gave depth carry their backward timings; the others are counted only here).

    Returns:
        ``{"frames", "wall_s", "frames_per_second", "overlap", "prefetch_workers", "backfill_s", "stages": {stage:
        {"frames", "median_s", "p90_s", "total_s"}}, "lanes": {lane: total seconds}}``; a
        stage appears when at least one frame ran it.
    """
    n = len(frame_timings)
    stages = {}
    names = [s for s in STAGES if any(s in t for t in frame_timings)]
    names += sorted({k for t in frame_timings for k in t} - set(STAGES))
    for name in names:
        v = np.array([t[name] for t in frame_timings if name in t], dtype=np.float64)
        stages[name] = {"frames": int(len(v)), "median_s": round(float(np.median(v)), 5),
                        "p90_s": round(float(np.percentile(v, 90)), 5), "total_s": round(float(v.sum()), 3)}
    lanes = {lane: round(sum(stages[s]["total_s"] for s in members if s in stages), 3)
             for lane, members in LANES.items()}
    return {
        "frames": n,
        "wall_s": round(float(wall_s), 3),
        "frames_per_second": round(n / wall_s, 3) if wall_s > 0 else None,
        "overlap": bool(overlap),
        "prefetch_workers": int(prefetch_workers) if overlap else 0,
        "backfill_s": round(float(backfill_s), 3),
        "stages": stages,
        "lanes": lanes,
    }
