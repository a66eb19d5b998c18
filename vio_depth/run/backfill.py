"""The offline backward pass: depth for the leading frames that had none (``RunSettings.backfill``).

The first frames of a run often have no depth: no keyframe to pair with yet, or too little
motion. Once the forward pass is over, :func:`backfill_leading_frames` runs a fresh pipeline
backwards from a little beyond them, so each meets keyframes from its future;
:func:`backfill_pass` hands the frames that now have depth to the run's writer again (marked
``backfilled``, not journaled a second time). The features the forward pass extracted for
those frames are reused (:func:`~vio_depth.run.frame_loop.keep_features`).
"""

from __future__ import annotations

import logging
import time

from matchers import Features

from ..io import Sequence
from ..pipeline import FrameStatus, Pipeline
from .frame_loop import prepare_frame
from .frame_writer import FrameWriter
from .interrupt import raise_if_interrupted
from .overlap import OrderedWriter, Prefetcher

log = logging.getLogger(__name__)


def backfill_leading_frames(sequence: Sequence, pipeline: Pipeline, results: dict, n: int, *,
                            overlap: bool = False, features: dict | None = None, workers: int = 1) -> dict:
    """Results with depth for the leading frames that had none, from a backward pass.

    The leading frames are those before the first frame with depth whose failure is about
    pairing, points or poses (not a missing disparity); when none has depth, every frame if the
    pose source tracks (the odometry's worker may have posed them at the end of the sequence:
    :meth:`Pipeline.finish_sequence`) and some frame had no pose, else none. A fresh pipeline with the same settings
    (its points window inline) processes frames ``last .. 0`` in reverse order, where
    ``last`` lies ``2 * buffer_size`` frames beyond the last leading frame, so each leading
    frame meets keyframes from its future. ``results`` maps each index to anything with ``has_depth`` and ``status`` (a
    :class:`FrameResult`); ``overlap`` prepares the frames in ``workers`` worker threads;
    ``features`` maps indices to features the forward pass extracted (not extracted again). Returns
    ``{index: (frame, FrameResult)}`` for the frames that now have depth.
    """
    first_ok = next((i for i in range(n) if results[i].has_depth), None)
    if first_ok is None:  # none had depth: the frames a tracking pose source could pose only at the end
        first_ok = n if pipeline.tracker is not None and any(results[i].status == FrameStatus.NO_POSE
                                                             for i in range(n)) else 0
    if first_ok == 0:
        return {}
    lead = [i for i in range(first_ok)
            if results[i].status not in (FrameStatus.NO_DISPARITY, FrameStatus.INVALID_DISPARITY,
                                         FrameStatus.CORRUPT_IMAGE)]
    if not lead:
        return {}
    # a few frames, offline: a worker would only add its start; the odometry's landmarks (--points vio)
    # exist only for frames it tracked live, which the leading ones were not: two-view points instead
    backward = pipeline.fresh(inline_window=True, offline_points=True)
    last = min(n - 1, lead[-1] + 2 * pipeline.settings.pairing.buffer_size)
    out = {}
    features = {} if features is None else features
    with Prefetcher(lambda i, turn=None: prepare_frame(sequence, backward, i, features.get(i), turn),
                    range(last, -1, -1), workers + 1, threaded=overlap, workers=workers,
                    ordered=backward.tracked is not None) as frames:
        for i in range(last, -1, -1):
            raise_if_interrupted()
            prepared = frames.get()
            res = backward.process_prepared(prepared)
            if i in lead and res.depth is not None:
                out[i] = (prepared.frame, res)
    log.info("backfill: %d of %d leading frames got depth from later keyframes", len(out), len(lead))
    return out


def backfill_pass(sequence: Sequence, pipeline: Pipeline, n: int, frames_out: FrameWriter, writer: OrderedWriter,
                  features: dict[int, Features], *, overlap: bool, workers: int) -> float:
    """The backward pass after the forward one: each leading frame that now has depth is
    marked ``backfilled`` (its reason says so) and handed to ``writer`` again, latest first,
    without a journal line. ``features`` (emptied here) are the forward pass's kept features.
    Returns the seconds it took."""
    t = time.perf_counter()
    back = backfill_leading_frames(sequence, pipeline, frames_out.results, n, overlap=overlap, features=features,
                                   workers=workers)
    features.clear()
    for i, (frame, res) in back.items():
        res.backfilled = True
        res.reason = f"offline backfill, paired with a later keyframe; {res.reason}".rstrip("; ")
        frames_out.results[i] = res
        writer.submit(frames_out.job(i, frame, res, journal=False))
    return time.perf_counter() - t
