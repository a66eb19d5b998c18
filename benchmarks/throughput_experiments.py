"""How to overlap a run on 2 cores: the measurements behind :mod:`vio_depth.run.overlap` (issue 11).

The same ``run_sequence`` call (1242x375 rendered street, SIMULATED disparity files, no
evaluation, no backward pass, outputs written) in variants, interleaved ``--repeats``
times, best of each:

* ``sequential``: every stage in the calling thread (``overlap=False``); also with
  ``cv2.setNumThreads(1)``;
* ``threads``: prefetch (decode, SIFT, disparity) in one thread per core (2), writer in a
  thread, OpenCV's pool reduced to the cores left over (1 on 2 cores) and the BLAS pool
  to 1 thread (the default);
* ``threads, BLAS pool unlimited``: the same with numpy's BLAS at its own thread count;
* ``threads, 1 prefetch thread``: the same with a single prefetch thread;
* ``threads, 1 prefetch thread, cv2 2 threads``: that with OpenCV's 2 threads;
* ``threads, SIFT in pipeline``: the prefetch threads decode and read the disparity only;
  SIFT of frame t+1 then no longer runs while frame t is matched and fitted;
* ``process prefetch``: the prefetch in one separate process (``spawn``; the child opens the
  sequence and builds its own pipeline; image, features and disparity are pickled back),
  writer in a thread.

    python benchmarks/throughput_experiments.py [--frames 60] [--repeats 2]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import os
import shutil
import sys
import tempfile
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import throughput_data as data  # noqa: E402

import vio_depth.run.frame_loop as frame_loop  # noqa: E402
import vio_depth.run.runner as runner  # noqa: E402
from vio_depth import Pipeline, PipelineSettings, open_sequence, run_sequence  # noqa: E402
from vio_depth.pipeline import PreparedFrame  # noqa: E402
from vio_depth.run import RunSettings  # noqa: E402
from vio_depth.run.overlap import Prefetcher, blas_threads, overlap_opencv_threads, prefetch_workers  # noqa: E402

# ----------------------------------------------------------------------------- SIFT in the pipeline lane


class SiftInPipeline(Pipeline):
    """``prepare`` decodes and reads the disparity; features are extracted in ``process_prepared``."""

    def prepare(self, frame, features=None):
        t = time.perf_counter()
        image = frame.image()
        frame = replace(frame, load_image=lambda: image)
        timings = {"image": time.perf_counter() - t}
        t = time.perf_counter()
        disparity = self.disparity_source(frame)
        timings["disparity"] = time.perf_counter() - t
        return PreparedFrame(frame, None, disparity, timings)

    def process_prepared(self, prepared):
        t = time.perf_counter()
        features = self.points.matcher.extract(prepared.frame.image())
        prepared.timings["features"] = time.perf_counter() - t
        return super().process_prepared(replace(prepared, features=features))


# ----------------------------------------------------------------------------- prefetch in a process
_CHILD: dict = {}


def _child_init(root: str, settings: PipelineSettings, cv_threads: int) -> None:
    cv2.setNumThreads(cv_threads)
    seq = open_sequence(root)
    _CHILD.update(sequence=seq, pipeline=Pipeline(settings, sequence=seq))


def _child_prepare(i: int):
    t = time.perf_counter()
    frame = _CHILD["sequence"][i]
    load = time.perf_counter() - t
    p = _CHILD["pipeline"].prepare(frame)
    p.timings["load"] = load
    return p.frame.image(), p.features, p.disparity, p.timings


class ProcessPrefetcher:
    """Drop-in for :class:`vio_depth.run.overlap.Prefetcher` that prepares frames in a child process."""

    context: dict = {}

    def __init__(self, produce, indices, depth: int = 2, *, threaded: bool = True, workers: int = 1, name: str = ""):
        c = self.context
        self._sequence = c["sequence"]
        self._pool = cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_child_init,
                                            initargs=(str(c["sequence"].root), c["settings"], cv2.getNumThreads()))
        self._indices = iter(indices)
        self._pending: deque = deque()
        for _ in range(depth + 1):
            self._submit()

    def _submit(self) -> None:
        i = next(self._indices, None)
        if i is not None:
            self._pending.append((i, self._pool.submit(_child_prepare, i)))

    def get(self):
        i, future = self._pending.popleft()
        image, features, disparity, timings = future.result()
        self._submit()
        frame = replace(self._sequence[i], load_image=lambda: image)
        return PreparedFrame(frame, features, disparity, timings)

    def close(self) -> None:
        self._pool.shutdown(cancel_futures=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ----------------------------------------------------------------------------- driver
def run_variant(variant: str, view: Path, out: Path) -> float:
    seq = open_sequence(view)
    settings = PipelineSettings.from_presets(pairing="kitti")
    settings = replace(settings, disparity=replace(settings.disparity, source="files", path=str(view / "disparity")))
    run = RunSettings(evaluate=False, backfill=False)
    pipeline = (SiftInPipeline if variant == "threads, SIFT in pipeline" else Pipeline)(settings, sequence=seq)
    cv_threads = cv2.getNumThreads()
    if variant.endswith("cv2 1 thread"):
        cv2.setNumThreads(1)
    if "1 prefetch thread" in variant:
        runner.prefetch_workers = lambda concurrent: 1
    if variant.endswith("cv2 2 threads"):
        runner.overlap_opencv_threads = lambda workers: 2
    if variant == "threads, BLAS pool unlimited":
        runner.blas_threads = lambda n: blas_threads(None)
    if variant == "process prefetch":
        ProcessPrefetcher.context = {"sequence": seq, "settings": settings}
        frame_loop.Prefetcher = ProcessPrefetcher  # the forward pass's (backfill is off)
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    try:
        run_sequence(seq, pipeline, out, run, progress=False, overlap=not variant.startswith("sequential"))
        return time.perf_counter() - t
    finally:
        frame_loop.Prefetcher = Prefetcher
        runner.overlap_opencv_threads = overlap_opencv_threads
        runner.prefetch_workers = prefetch_workers
        runner.blas_threads = blas_threads
        cv2.setNumThreads(cv_threads)


VARIANTS = ("sequential", "sequential, cv2 1 thread", "threads", "threads, BLAS pool unlimited",
            "threads, 1 prefetch thread",
            "threads, 1 prefetch thread, cv2 2 threads", "threads, SIFT in pipeline", "process prefetch")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--cache", type=Path, default=data.DEFAULT_CACHE)
    args = ap.parse_args(argv)
    rendered = data.prepare_rendered("street_kitti", args.cache)
    view = data.make_view(rendered, rendered / "disparity", args.frames, args.cache / f"view_street_kitti_{args.frames}")
    out = Path(tempfile.mkdtemp(prefix="throughput_experiments_")) / "out"
    print(f"{args.frames} frames of 1242x375 (SIMULATED disparity files), {os.cpu_count()} CPUs, OpenCV "
          f"{cv2.getNumThreads()} threads, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}")
    best = {v: np.inf for v in args.variants}
    loads = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        for v in args.variants:
            best[v] = min(best[v], run_variant(v, view, out))
        loads.append(os.getloadavg()[0])
    shutil.rmtree(out.parent, ignore_errors=True)
    base = best.get("sequential")
    for v in args.variants:
        rel = f"   {base / best[v]:.2f} x sequential" if base else ""
        print(f"  {v:42s} {args.frames / best[v]:6.2f} frames/s{rel}")
    print("  load average (1 min) before/after each repeat: " + " ".join(f"{x:.2f}" for x in loads))
    return 0


if __name__ == "__main__":
    sys.exit(main())
