"""Overlap of a run's stages: the next frames are prepared in one worker, the outputs written in another.

A run has three lanes (docs/benchmarks.md, "Throughput"):

* **prefetch** (:class:`Prefetcher`): the pipeline's stateless stages of the next frames,
  ahead of time: reading and decoding the image, feature extraction and the disparity map
  (file, SIMULATED or model inference; :meth:`vio_depth.pipeline.Pipeline.prepare`); a
  tracker's (KLT's) frames take turns for the image and the tracks, in frame order, while
  their disparity maps are made concurrently (``ordered``);
* **pipeline** (the calling thread): the stateful stages in frame order: pairing,
  matching, triangulation, fit, depth (:meth:`~vio_depth.pipeline.Pipeline.process_prepared`);
* **writer** (:class:`OrderedWriter`): encoding and writing the outputs (depth PNG,
  uncertainty, exports), the ground-truth evaluation and the journal line of each frame,
  in frame order.

Workers are **threads**: OpenCV, numpy and torch release the GIL in their heavy calls
(decoding, SIFT, BLAS, PNG encoding, inference), and a thread shares the sequence, the
matcher and the disparity model without copying them. A prefetch *process* was measured
slower on 2 cores (it starts a second interpreter and pickles each frame's image,
disparity and features back), and SIFT extraction of frame t+1 overlapping the matching
and fit of frame t is what makes the overlap pay (docs/benchmarks.md, "Throughput").
While a run overlaps, OpenCV's own thread pool is reduced to the cores the other lanes
leave over (:func:`overlap_opencv_threads`: 1 on 2 cores), since on 2 shared cores its
second thread slowed SIFT down, and the BLAS pool (numpy's OpenBLAS: descriptor matching,
fits) to one thread (:func:`blas_threads`): its idle threads spin while waiting for work,
and beside the prefetch threads that cost a quarter of the run's CPU time
(docs/benchmarks.md, "Throughput"). For the same reason torch's pool (SIFT's bfloat16
descriptor screen) runs on one thread while several prefetch threads run (:class:`TorchThreads`).

Guarantees:

* **Bounded memory**: each worker is at most ``depth`` items ahead; a full queue blocks the
  producer.
* **Same results**: the same code runs in the same order per lane; the pipeline's state
  is only touched by the calling thread, the outputs only by the writer, one frame after
  the other. ``threaded=False`` runs everything inline (the sequential run), which gives
  byte-identical outputs (tests/vio_depth/run/test_overlap.py).
* **Errors**: the exception a worker raises is re-raised, as the same object, in the
  calling thread (so the command line prints the same one-line error as a sequential run);
  the writer skips every job after a failed one, so the journal never records a frame
  whose files are not complete, and the staging folder stays resumable.
* **Interruption**: :meth:`OrderedWriter.cancel` lets the job in progress finish (every
  file is written under a temporary name and renamed, so none is ever half-written) and
  skips the rest.
"""

from __future__ import annotations

import contextlib
import os
import queue
import sys
import threading
from typing import Any, Callable, Iterable, Iterator

import cv2
from threadpoolctl import threadpool_limits

from .interrupt import raise_if_interrupted

#: items a worker may run ahead of the pipeline (prefetched frames, results waiting to be written)
DEFAULT_DEPTH = 2
_POLL_S = 0.05


#: most prefetch threads a run uses
MAX_PREFETCH_WORKERS = 4


def prefetch_workers(concurrent: bool, cpus: int | None = None) -> int:
    """Prefetch threads of an overlapped run: one per core up to :data:`MAX_PREFETCH_WORKERS`
    when the preparation may run in several threads at once (``concurrent``: SIFT features
    and no model inference), else 1. On 2 cores: 2, i.e. frames t+1 and t+2 are prepared
    while frame t is processed and frame t-1 written."""
    cpus = (os.cpu_count() or 1) if cpus is None else cpus
    return max(1, min(cpus, MAX_PREFETCH_WORKERS)) if concurrent else 1


def overlap_opencv_threads(workers: int = 1, cpus: int | None = None) -> int:
    """OpenCV's thread count while a run overlaps: the cores left over by ``workers``
    prefetch threads, the pipeline and the writer, at least 1 (on 2 cores: 1, OpenCV's
    pool off)."""
    cpus = (os.cpu_count() or 1) if cpus is None else cpus
    return max(1, cpus - workers - 2)


@contextlib.contextmanager
def opencv_threads(n: int | None) -> Iterator[None]:
    """``cv2.setNumThreads(n)`` for the duration (None: unchanged), restored afterwards.

    OpenCV's pool and the run's own threads compete for the same cores; on 2 shared cores
    SIFT with OpenCV's 2 threads was slower than with 1 (docs/benchmarks.md). The thread
    count changes no result: SIFT sorts its keypoints whatever thread found them.
    """
    if n is None:
        yield
        return
    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


@contextlib.contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """The BLAS libraries' thread pools (OpenBLAS, MKL: numpy's matrix products) limited to
    ``n`` threads for the duration (None: unchanged), restored afterwards.

    A matrix product splits its output between threads; each element is the same dot
    product whatever the thread count, so results do not change (the overlapped run's
    outputs equal the sequential run's byte for byte: tests/vio_depth/run/test_overlap.py).
    """
    if n is None:
        yield
        return
    with threadpool_limits(limits=int(n), user_api="blas"):
        yield


class TorchThreads:
    """Context: torch's intra-op thread pool limited to ``n`` threads (None: unchanged) from
    the moment torch is loaded until the context ends, then restored. torch's setting is
    process-wide.

    A run limits it when several prefetch threads keep every core busy with SIFT: torch then
    only runs SIFT's bfloat16 descriptor screen (:mod:`matchers.nearest`) in the pipeline
    lane, and its idle OpenMP threads would spin beside SIFT like OpenBLAS's. The matcher
    imports torch on its first large product, during the run, so the run calls
    :meth:`poll` after each frame; torch is never imported here.
    """

    def __init__(self, n: int | None):
        self.n = n
        self._torch = None
        self._before: int | None = None

    def poll(self) -> None:
        """Apply the limit if torch has been loaded since the last call (cheap otherwise)."""
        if self.n is None or self._torch is not None:
            return
        torch = sys.modules.get("torch")
        if torch is not None and hasattr(torch, "set_num_threads"):  # not half-imported
            self._torch, self._before = torch, torch.get_num_threads()
            torch.set_num_threads(int(self.n))

    def __enter__(self) -> "TorchThreads":
        self.poll()
        return self

    def __exit__(self, *exc) -> None:
        if self._torch is not None:
            self._torch.set_num_threads(self._before)
            self._torch = self._before = None


class Prefetcher:
    """``produce(i)`` for each of ``indices``, delivered in order by :meth:`get`, at most
    ``depth`` values ahead, by ``workers`` threads (each produces whole items: with 2
    workers, frames t+1 and t+2 are prepared at the same time).

    With ``ordered``, ``produce(i, turn)`` gets a context manager ``turn``: the blocks under
    ``with turn:`` run one at a time, in the order of ``indices`` (a tracker follows the frames
    in order inside it while the rest of each item, e.g. its disparity, runs concurrently). An
    item that ends without entering its turn (an error before it) gives up its turn when it ends.

    Args:
        produce: index -> value (e.g. a prepared frame), or (index, turn) -> value with
            ``ordered``; may raise. With ``workers > 1`` it is called from several threads at once.
        indices: the indices, in the order :meth:`get` returns their values.
        depth: values claimed ahead of :meth:`get` (in production or waiting), at least ``workers``.
        threaded: False runs ``produce`` inline in :meth:`get` (the sequential run).
        workers: producing threads.
        ordered: hand ``produce`` its turn (above).
    """

    def __init__(self, produce: Callable[..., Any], indices: Iterable[int], depth: int = DEFAULT_DEPTH, *,
                 threaded: bool = True, workers: int = 1, ordered: bool = False, name: str = "vio-depth-prefetch"):
        self._produce = produce
        self._indices = list(indices)
        self._threaded = threaded
        self._ordered = ordered
        self._depth = max(1, depth, workers)
        self._cond = threading.Condition()
        self._claimed = 0  # positions handed to a worker so far
        self._delivered = 0  # positions returned by get()
        self._turn_at = 0  # the position whose turn it is: every earlier one has passed its turn
        self._passed: set[int] = set()  # later positions that passed their turn already
        self._ready: dict[int, tuple[Any, BaseException | None]] = {}
        self._stop = False
        self._threads = []
        if threaded:
            self._threads = [threading.Thread(target=self._work, name=f"{name}-{k}", daemon=True)
                             for k in range(max(1, workers))]
            for t in self._threads:
                t.start()

    def _work(self) -> None:
        while True:
            with self._cond:
                while (not self._stop and self._claimed < len(self._indices)
                       and self._claimed >= self._delivered + self._depth):
                    self._cond.wait()
                if self._stop or self._claimed >= len(self._indices):
                    return
                pos = self._claimed
                self._claimed += 1
            try:
                item = (self._call(pos), None)
            except BaseException as exc:  # handed to the consumer, raised there
                item = (None, exc)
            with self._cond:
                self._pass_turn(pos)  # an item that never entered its turn gives it up here
                self._ready[pos] = item
                if item[1] is not None:
                    self._stop = True  # claim nothing more; earlier positions still complete
                self._cond.notify_all()

    def _call(self, pos: int) -> Any:
        if not self._ordered:
            return self._produce(self._indices[pos])
        return self._produce(self._indices[pos], self._turn(pos) if self._threaded else contextlib.nullcontext())

    @contextlib.contextmanager
    def _turn(self, pos: int) -> Iterator[None]:
        """Waits until every earlier position passed its turn; passes this one's on exit."""
        with self._cond:
            while self._turn_at < pos:
                self._cond.wait()
        try:
            yield
        finally:
            with self._cond:
                self._pass_turn(pos)

    def _pass_turn(self, pos: int) -> None:
        """(with ``self._cond`` held) ``pos`` passed its turn; idempotent."""
        if pos >= self._turn_at:
            self._passed.add(pos)
            while self._turn_at in self._passed:
                self._passed.discard(self._turn_at)
                self._turn_at += 1
            self._cond.notify_all()

    def get(self) -> Any:
        """The next value; re-raises what ``produce`` raised for it.

        Raises:
            StopIteration: every index was delivered.
        """
        if not self._threaded:
            if self._delivered >= len(self._indices):
                raise StopIteration
            self._delivered += 1
            return self._call(self._delivered - 1)
        with self._cond:
            while self._delivered not in self._ready:
                if self._delivered >= len(self._indices) or not any(t.is_alive() for t in self._threads):
                    raise StopIteration
                raise_if_interrupted()  # a slow producer does not hold up Ctrl-C
                self._cond.wait(_POLL_S)
            value, exc = self._ready.pop(self._delivered)
            self._delivered += 1
            self._cond.notify_all()
        if exc is not None:
            raise exc
        return value

    def close(self) -> None:
        """Stop producing and wait for the workers (items in production are finished, then dropped)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        for t in self._threads:
            t.join()
        self._ready.clear()

    def __enter__(self) -> "Prefetcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class OrderedWriter:
    """Runs submitted jobs one after the other, in submission order, at most ``depth`` waiting.

    The first job that raises stops the writer: later jobs are skipped and the exception is
    re-raised by the next :meth:`submit` or by :meth:`finish`.

    Args:
        depth: jobs waiting at most (``submit`` blocks beyond).
        threaded: False runs each job inline in :meth:`submit` (the sequential run).
    """

    def __init__(self, depth: int = DEFAULT_DEPTH, *, threaded: bool = True, name: str = "vio-depth-writer"):
        self._threaded = threaded
        self._error: BaseException | None = None
        self._cancel = threading.Event()
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._work, name=name, daemon=True)
            self._thread.start()

    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            if self._error is None and not self._cancel.is_set():
                try:
                    job()
                except BaseException as exc:  # re-raised in the submitting thread
                    self._error = exc

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def submit(self, job: Callable[[], None]) -> None:
        """Queue ``job`` (run it now when not threaded); re-raises an earlier job's error."""
        self._raise()
        if not self._threaded:
            job()
            return
        self._queue.put(job)

    def finish(self) -> None:
        """Wait until every submitted job ran; re-raises the first error."""
        if self._thread is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self._raise()

    def drain_quietly(self) -> None:
        """After an error elsewhere: let the jobs already submitted run (unless one fails:
        the rest are then skipped), wait for them, and raise nothing (the caller is
        raising its own error)."""
        if self._thread is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def cancel(self) -> None:
        """Skip the jobs not started yet and wait for the one in progress (its files complete)."""
        self._cancel.set()
        if self._thread is None:
            return
        while self._thread.is_alive():
            try:
                self._queue.put(None, timeout=_POLL_S)
            except queue.Full:
                try:
                    self._queue.get_nowait()
                except queue.Empty:
                    pass
                continue
            self._thread.join()
