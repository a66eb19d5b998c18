"""The forward pass of a run: every frame in order through the pipeline, handed to the writer.

Frames are prepared (loaded, features, disparity: the pipeline's stateless stages) by a
:class:`~vio_depth.run.overlap.Prefetcher`, processed in order by the pipeline's stateful
stages in this thread, and handed to the :class:`~vio_depth.run.overlap.OrderedWriter` as
:meth:`~vio_depth.run.frame_writer.FrameWriter.job`. A resumed run goes through the same loop:
the writer replays the journaled frames instead of writing them
(:mod:`vio_depth.run.resume`). The features of the first frames are kept for the backward pass
(:mod:`vio_depth.run.backfill`).
"""

from __future__ import annotations

import sys
import time
from typing import ContextManager

from tqdm import tqdm

from matchers import Features

from ..io import Sequence
from ..pipeline import Pipeline, PreparedFrame
from .frame_writer import FrameWriter
from .interrupt import raise_if_interrupted
from .overlap import OrderedWriter, Prefetcher, TorchThreads


def prepare_frame(sequence: Sequence, pipeline: Pipeline, i: int, features: Features | None = None,
                  in_order: ContextManager | None = None) -> PreparedFrame:
    """Frame ``i`` through the pipeline's stateless stages (timed: ``load`` and the stages);
    ``features``: the frame's features when already extracted; ``in_order``: the frame's turn
    for a tracker (:meth:`vio_depth.pipeline.Pipeline.prepare`)."""
    t = time.perf_counter()
    frame = sequence[i]
    load = time.perf_counter() - t
    prepared = pipeline.prepare(frame, features, in_order)
    prepared.timings["load"] = load
    return prepared


def keep_features(i: int, first_ok: int | None, buffer_size: int) -> bool:
    """Whether frame ``i``'s features may serve the backward pass: it reaches at most
    ``2 * buffer_size`` frames beyond the frame before the first one with depth; while no
    frame has depth yet, at most ``4 * buffer_size`` frames are kept (memory stays bounded)."""
    if first_ok is None:
        return i < 4 * buffer_size
    return i < first_ok + 2 * buffer_size


def forward_pass(sequence: Sequence, pipeline: Pipeline, n: int, frames_out: FrameWriter, writer: OrderedWriter, *,
                 progress: bool | None, overlap: bool, workers: int, torch_threads: TorchThreads | None,
                 keep: bool) -> dict[int, Features]:
    """Frames ``0 .. n-1`` through ``pipeline``, each handed to ``writer`` as ``frames_out``'s job.

    Args:
        progress: show a progress bar (None = only when stderr is a terminal).
        overlap: prepare frames in ``workers`` threads (False: in this thread).
        torch_threads: polled after each frame (a matcher may load torch during the run), or None.
        keep: keep the features of the first frames for the backward pass (:func:`keep_features`).

    Returns:
        frame index -> features, of the kept frames.
    """
    bar = tqdm(range(n), desc=f"vio-depth {sequence.name}", unit="frame",
               disable=(not sys.stderr.isatty()) if progress is None else not progress, file=sys.stderr)
    with_depth = 0
    features: dict[int, Features] = {}
    first_ok = None
    # a tracker's frames take turns for their tracking (their disparity runs concurrently)
    with Prefetcher(lambda i, turn=None: prepare_frame(sequence, pipeline, i, in_order=turn), range(n), workers + 1,
                    threaded=overlap, workers=workers, ordered=pipeline.tracked is not None) as frames:
        for i in bar:
            raise_if_interrupted()  # a signal during the last frame: here, with no lock held
            prepared = frames.get()
            res = pipeline.process_prepared(prepared)
            if torch_threads is not None:
                torch_threads.poll()
            frames_out.results[i] = res
            writer.submit(frames_out.job(i, prepared.frame, res))
            with_depth += res.has_depth
            first_ok = i if first_ok is None and res.has_depth else first_ok
            if keep and keep_features(i, first_ok, pipeline.settings.pairing.buffer_size):
                features[i] = prepared.features
            bar.set_postfix(depth=f"{with_depth}/{i + 1}")
    return features
