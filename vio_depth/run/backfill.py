"""The offline backward pass: depth for the leading frames that had none (``RunSettings.backfill``).

The first frames of a run often have no depth: no keyframe to pair with yet, or too little
motion. Once the forward pass is over, :func:`backfill_leading_frames` runs a fresh pipeline
backwards from a little beyond them, so each meets keyframes from its future;
:func:`backfill_pass` hands the frames that now have depth to the run's writer again (marked
``backfilled``, not journaled a second time). The features the forward pass extracted for
those frames are reused (:func:`~vio_depth.run.frame_loop.keep_features`).

A run in which no frame got depth while its tracking pose source (the odometry) posed frames
only at the sequence's end (:meth:`~vio_depth.pipeline.Pipeline.finish_sequence`: its worker's
start came after the last frame) is first replayed forwards with those poses
(:func:`replay_posed_late`), so that its later frames pair with earlier keyframes; the backward
pass then covers the frames before the first that has depth.
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


def _replay(sequence: Sequence, pipeline: Pipeline, order: range, wanted: set[int], *, overlap: bool,
            features: dict, workers: int) -> dict:
    """``{index: (frame, FrameResult)}`` for the ``wanted`` frames with depth when a fresh
    pipeline (its points window inline, two-view points for ``--points vio``: the odometry's
    landmarks exist only for frames it tracked live) processes the frames in ``order``."""
    fresh = pipeline.fresh(inline_window=True, offline_points=True)
    out = {}
    with Prefetcher(lambda i, turn=None: prepare_frame(sequence, fresh, i, features.get(i), turn),
                    order, workers + 1, threaded=overlap, workers=workers,
                    ordered=fresh.tracked is not None) as frames:
        for i in order:
            raise_if_interrupted()
            prepared = frames.get()
            res = fresh.process_prepared(prepared)
            if i in wanted and res.depth is not None:
                out[i] = (prepared.frame, res)
    return out


def replay_posed_late(sequence: Sequence, pipeline: Pipeline, results: dict, n: int, *, overlap: bool = False,
                      features: dict | None = None, workers: int = 1) -> dict:
    """Results with depth from a forward replay of a run in which no frame had depth and some had
    no pose while the pipeline's pose source tracks (module docstring), else ``{}``. ``results``,
    ``overlap``, ``features``, ``workers`` and the return value as :func:`backfill_leading_frames`'s."""
    if pipeline.tracker is None or any(results[i].has_depth for i in range(n)) \
            or not any(results[i].status == FrameStatus.NO_POSE for i in range(n)):
        return {}
    out = _replay(sequence, pipeline, range(n), set(range(n)), overlap=overlap, features=features or {},
                  workers=workers)
    log.info("backfill: %d of %d frames got depth from a forward replay with the poses found at the end", len(out), n)
    return out


def backfill_leading_frames(sequence: Sequence, pipeline: Pipeline, results: dict, n: int, *,
                            overlap: bool = False, features: dict | None = None, workers: int = 1) -> dict:
    """Results with depth for the leading frames that had none, from a backward pass.

    The leading frames are those before the first frame with depth whose failure is about
    pairing, points or poses (not a missing disparity). A fresh pipeline with the same settings
    (:func:`_replay`) processes frames ``last .. 0`` in reverse order, where ``last`` lies
    ``2 * buffer_size`` frames beyond the last leading frame, so each leading frame meets
    keyframes from its future. ``results`` maps each index to anything with ``has_depth`` and
    ``status`` (a :class:`FrameResult`); ``overlap`` prepares the frames in ``workers`` worker
    threads; ``features`` maps indices to features the forward pass extracted (not extracted
    again). Returns ``{index: (frame, FrameResult)}`` for the frames that now have depth.
    """
    first_ok = next((i for i in range(n) if results[i].has_depth), None)
    if first_ok is None or first_ok == 0:
        return {}
    lead = [i for i in range(first_ok)
            if results[i].status not in (FrameStatus.NO_DISPARITY, FrameStatus.INVALID_DISPARITY,
                                         FrameStatus.CORRUPT_IMAGE)]
    if not lead:
        return {}
    # a few frames, offline: a worker would only add its start
    last = min(n - 1, lead[-1] + 2 * pipeline.settings.pairing.buffer_size)
    out = _replay(sequence, pipeline, range(last, -1, -1), set(lead), overlap=overlap, features=features or {},
                  workers=workers)
    log.info("backfill: %d of %d leading frames got depth from later keyframes", len(out), len(lead))
    return out


def backfill_pass(sequence: Sequence, pipeline: Pipeline, n: int, frames_out: FrameWriter, writer: OrderedWriter,
                  features: dict[int, Features], *, overlap: bool, workers: int) -> float:
    """The backward pass after the forward one (after a forward replay where one is due: module
    docstring): each frame that now has depth is marked ``backfilled`` (its reason says how) and
    handed to ``writer`` again without a journal line. ``features`` (emptied here) are the forward pass's kept features.
    Returns the seconds it took."""
    t = time.perf_counter()
    forward = replay_posed_late(sequence, pipeline, frames_out.results, n, overlap=overlap, features=features,
                                workers=workers)
    _hand_over(forward, "offline replay with the poses found at the end of the sequence", frames_out, writer)
    back = backfill_leading_frames(sequence, pipeline, frames_out.results, n, overlap=overlap, features=features,
                                   workers=workers)
    features.clear()
    _hand_over(back, "offline backfill, paired with a later keyframe", frames_out, writer)
    return time.perf_counter() - t


def _hand_over(results: dict, why: str, frames_out: FrameWriter, writer: OrderedWriter) -> None:
    """Each of ``results`` (``{index: (frame, FrameResult)}``) marked ``backfilled`` with ``why``
    before its reason, made the run's result of its frame and handed to ``writer`` (no journal line)."""
    for i, (frame, res) in results.items():
        res.backfilled = True
        res.reason = f"{why}; {res.reason}".rstrip("; ")
        frames_out.results[i] = res
        writer.submit(frames_out.job(i, frame, res, journal=False))
