"""Issue 11: the overlapped run (prefetch and writer threads) gives the sequential run's outputs
byte for byte, keeps memory bounded, surfaces a worker's error as the same one-line error,
and an interruption leaves no half-written file and a resumable staging folder."""

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from vio_core.errors import InputError
from vio_depth import Pipeline, open_sequence, run_sequence
from vio_depth.cli import main
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.io.depth_png import read_depth_png
from vio_depth.run import (
    OrderedWriter,
    Prefetcher,
    RunSettings,
    Terminated,
    raise_terminated,
    read_frames_jsonl,
    staging_path,
)
from vio_depth.run.folder import JOURNAL_NAME

VOLATILE = ("seconds", "timings")


# --------------------------------------------------------------------------- the workers
@pytest.mark.parametrize("threaded, workers", [(True, 1), (True, 2), (True, 4), (False, 1)])
def test_prefetcher_keeps_order_and_stays_bounded(threaded, workers):
    produced = []
    rng = np.random.default_rng(workers)
    delays = rng.uniform(0, 0.004, 40)  # items finish out of order with several workers

    def produce(i):
        time.sleep(delays[i])
        produced.append(i)
        return i * i

    depth = workers + 1
    with Prefetcher(produce, range(40), depth, threaded=threaded, workers=workers) as p:
        got = []
        for _ in range(40):
            time.sleep(0.002)
            got.append(p.get())
            assert len(produced) <= len(got) + depth  # never more than depth values ahead
        with pytest.raises(StopIteration):
            p.get()
    assert got == [i * i for i in range(40)]


@pytest.mark.parametrize("workers", [1, 3])
def test_prefetcher_reraises_the_workers_exception_object(workers):
    boom = InputError("frame 3: unreadable")

    def produce(i):
        if i == 3:
            raise boom
        time.sleep(0.001 * (i % 2))
        return i

    with Prefetcher(produce, range(10), workers + 1, workers=workers) as p:
        assert [p.get() for _ in range(3)] == [0, 1, 2]  # the values before the failure come first
        with pytest.raises(InputError) as info:
            p.get()
    assert info.value is boom


@pytest.mark.parametrize("threaded, workers", [(True, 2), (True, 4), (False, 1)])
def test_ordered_prefetcher_takes_turns_in_index_order_and_overlaps_the_rest(threaded, workers):
    """A tracker's frames: the block under ``turn`` runs one at a time in the order of the
    indices (here reversed, as in the backward pass), the rest of each item concurrently; an
    item that fails or skips its turn does not hold up the next ones."""
    rng = np.random.default_rng(workers)
    before, after = rng.uniform(0, 0.003, 30), rng.uniform(0, 0.006, 30)
    turns, inside, active, most = [], [0], [0], [0]
    lock = threading.Lock()
    indices = list(range(29, -1, -1))

    def produce(i, turn):
        with lock:
            active[0] += 1
            most[0] = max(most[0], active[0])
        try:
            return _item(i, turn)
        finally:
            with lock:
                active[0] -= 1

    def _item(i, turn):
        time.sleep(before[i])
        if i == 20:
            raise InputError("frame 20: unreadable")  # before its turn: gives the turn up by ending
        if i == 10:
            return -1  # no turn needed (features given)
        with turn:
            with lock:
                inside[0] += 1
                assert inside[0] == 1  # one at a time
            turns.append(i)
            time.sleep(0.0005)
            with lock:
                inside[0] -= 1
        time.sleep(after[i])
        return i

    got = []
    with Prefetcher(produce, indices, workers + 1, threaded=threaded, workers=workers, ordered=True) as p:
        for _ in indices:
            try:
                got.append(p.get())
            except InputError:
                got.append("error")
                break
    assert turns[: len([i for i in indices if i > 20])] == [i for i in indices if i > 20]
    assert turns == sorted(turns, reverse=True)  # taken in index order, never out of it
    assert got == [i for i in indices if i > 20] + ["error"]
    assert (most[0] > 1) == threaded and most[0] <= workers  # items were produced side by side


def test_prefetcher_close_stops_blocked_workers():
    p = Prefetcher(lambda i: i, range(10_000), depth=2, workers=2)
    assert p.get() == 0
    p.close()
    assert not any(t.name.startswith("vio-depth-prefetch") and t.is_alive() for t in threading.enumerate())


def test_writer_runs_in_order_and_skips_everything_after_a_failure():
    ran = []
    w = OrderedWriter(depth=2)
    boom = OSError(28, "No space left on device")

    def job(i):
        def run():
            if i == 4:
                raise boom
            ran.append(i)
        return run

    with pytest.raises(OSError) as info:
        for i in range(50):
            w.submit(job(i))
            time.sleep(0.002)
        w.finish()
    assert info.value is boom
    w.drain_quietly()
    assert ran == [0, 1, 2, 3]  # nothing after the failed job: the journal never runs ahead of the files


def test_writer_cancel_finishes_the_running_job_and_skips_the_rest():
    started, finished = threading.Event(), []
    gate = threading.Event()

    def slow():
        started.set()
        gate.wait(5)
        finished.append("slow")

    w = OrderedWriter(depth=4)
    w.submit(slow)
    w.submit(lambda: finished.append("later"))
    started.wait(5)
    threading.Timer(0.05, gate.set).start()
    w.cancel()
    assert finished == ["slow"]


# --------------------------------------------------------------------------- whole runs
def _files(out: Path) -> dict:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name not in ("frames.jsonl", "metrics.json", "vio-depth-run.json")}


def _records(out: Path):
    header, frames = read_frames_jsonl(out / "frames.jsonl")
    header.pop("command")  # --out and --no-overlap differ
    return header, [{k: v for k, v in f.items() if k not in VOLATILE} for f in frames]


def _metrics(out: Path) -> dict:
    m = json.loads((out / "metrics.json").read_text())
    for k in ("seconds", "timings"):
        m.pop(k)
    m["run"].pop("command")
    return m


@pytest.mark.parametrize("matcher", ["sift", "klt"])  # klt: the default with the sequence's poses
def test_overlapped_run_equals_the_sequential_run_byte_for_byte(mini_street, tmp_path, capsys, matcher):
    seq = mini_street(12)
    flags = ["--save-npy", "--save-ply", "sparse,dense:8", "--save-preview", "--uncertainty", "--no-progress",
             "--matcher", matcher]
    seq_out, ovl_out = tmp_path / "sequential", tmp_path / "overlapped"
    assert main(["run", str(seq), "--out", str(seq_out), "--no-overlap", *flags]) == 0
    assert main(["run", str(seq), "--out", str(ovl_out), *flags]) == 0
    files = _files(ovl_out)
    assert files == _files(seq_out)  # depth and uncertainty PNGs, npy, PLY, previews, trajectory
    assert sum(k.startswith("depth/") for k in files) == 12 and any(k.startswith("depth_npy/") for k in files)
    assert _records(ovl_out) == _records(seq_out)  # frames.jsonl minus timings
    assert _metrics(ovl_out) == _metrics(seq_out)
    assert _records(ovl_out)[1][0].get("backfilled") is True  # the backward pass ran in both
    t = json.loads((ovl_out / "metrics.json").read_text())["timings"]
    assert t["overlap"] is True and t["frames"] == 12 and t["frames_per_second"] > 0
    # one prefetch thread per core: SIFT's extract concurrently, klt's frames take turns for the tracks
    assert t["prefetch_workers"] == min(os.cpu_count(), 4)
    assert {"features", "matching", "triangulation", "write", "evaluation"} <= set(t["stages"])
    assert json.loads((seq_out / "metrics.json").read_text())["timings"]["overlap"] is False


def test_no_evaluation_skips_the_ground_truth_work(mini_street, tmp_path):
    path = mini_street(5)
    seq = open_sequence(path)
    run_sequence(seq, Pipeline(sequence=seq), tmp_path / "out", RunSettings(evaluate=False))
    _, frames = read_frames_jsonl(tmp_path / "out" / "frames.jsonl")
    assert all("evaluation" not in f["timings"] and f.get("abs_rel") is None for f in frames)
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["metrics"] == {} and metrics["timings"]["frames"] == 5


def _one_line(rc, err, *fragments):
    assert rc == 1, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in lines[0], lines[0]


def _journaled(out: Path) -> list[dict]:
    lines = (staging_path(out) / JOURNAL_NAME).read_text().splitlines()
    return [json.loads(ln) for ln in lines[1:]]


def test_a_failing_prefetch_worker_stops_the_run_with_one_line(mini_street, tmp_path, capsys):
    seq = mini_street(9)
    bad = seq / "images" / "000006.jpg"
    bad.write_bytes(bad.read_bytes()[:3000])
    out = tmp_path / "out"
    rc = main(["run", str(seq), "--out", str(out), "--no-progress"])
    _one_line(rc, capsys.readouterr().err, "000006.jpg", "--resume continues it")
    assert not out.exists()
    journaled = _journaled(out)
    assert [r["frame"] for r in journaled] == list(range(6))  # the frames before it were completed
    assert not list(staging_path(out).rglob("*.partial"))


def test_a_failing_writer_worker_stops_the_run_with_one_line(mini_street, tmp_path, capsys):
    """The ground-truth depth of frame 5 is damaged: it is read by the evaluation, in the writer."""
    seq_dir = mini_street(9)
    seq = open_sequence(seq_dir)
    source = create_disparity_source(DisparitySettings(), seq)
    disp = tmp_path / "disparity"
    disp.mkdir()
    for i in range(len(seq)):
        np.save(disp / f"{seq[i].stem}.npy", source(seq[i]).astype(np.float32))
    gt = seq_dir / "depth" / "000005.png"
    gt.write_bytes(gt.read_bytes()[:500])
    out = tmp_path / "out"
    rc = main(["run", str(seq_dir), "--out", str(out), "--disparity-dir", str(disp), "--no-progress"])
    _one_line(rc, capsys.readouterr().err, "000005.png", "--resume continues it")
    assert [r["frame"] for r in _journaled(out)] == list(range(5))  # nothing journaled past the failure


class _InterruptAt:
    """A pipeline wrapper that raises KeyboardInterrupt (as Ctrl-C does) when frame ``k`` is processed."""

    def __init__(self, pipeline: Pipeline, k: int):
        self._pipeline, self._k = pipeline, k

    def __getattr__(self, name):
        return getattr(self._pipeline, name)

    def process_prepared(self, prepared):
        if prepared.frame.index == self._k:
            raise KeyboardInterrupt
        return self._pipeline.process_prepared(prepared)


def test_interruption_leaves_complete_files_and_a_resumable_folder(mini_street, tmp_path):
    path = mini_street(10)
    seq = open_sequence(path)
    out = tmp_path / "out"
    pipeline = _InterruptAt(Pipeline(sequence=seq), 7)
    with pytest.raises(KeyboardInterrupt):
        run_sequence(seq, pipeline, out, RunSettings(uncertainty=True))
    staging = staging_path(out)
    assert not out.exists() and not list(staging.rglob("*.partial"))
    journaled = _journaled(out)
    assert [r["frame"] for r in journaled] == list(range(7))
    for r in journaled:  # every journaled frame's files are complete
        if r["alpha"] is not None:
            assert read_depth_png(staging / "depth" / f"{r['stem']}.png").shape == (256, 640)
            assert read_depth_png(staging / "uncertainty" / f"{r['stem']}.png").shape == (256, 640)
    summary = run_sequence(seq, Pipeline(sequence=seq), out, RunSettings(uncertainty=True), mode="resume")
    assert summary.resumed_frames == 7 and summary.frames_processed == 10


class _SignalAt(_InterruptAt):
    """A pipeline wrapper that sends this process ``signum`` while frame ``k`` is processed."""

    def __init__(self, pipeline: Pipeline, k: int, signum: int):
        super().__init__(pipeline, k)
        self._signum = signum

    def process_prepared(self, prepared):
        if prepared.frame.index == self._k:
            signal.raise_signal(self._signum)
        return self._pipeline.process_prepared(prepared)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_signal_mid_frame_finishes_that_frame_then_stops_resumably(mini_street, tmp_path, signum):
    """Ctrl-C / SIGTERM land between frames (vio_depth.run.interrupt), not inside a worker
    thread's lock: frame k is completed and journaled, the run stops, --resume finishes it."""
    path = mini_street(10)
    seq = open_sequence(path)
    out = tmp_path / "out"
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, raise_terminated)
    try:
        with pytest.raises(Terminated if signum == signal.SIGTERM else KeyboardInterrupt):
            run_sequence(seq, _SignalAt(Pipeline(sequence=seq), 6, signum), out, RunSettings())
    finally:
        for s, h in before.items():
            signal.signal(s, h)
    assert not out.exists()
    assert [r["frame"] for r in _journaled(out)] == list(range(7))
    summary = run_sequence(seq, Pipeline(sequence=seq), out, RunSettings(), mode="resume")
    assert summary.resumed_frames == 7 and summary.frames_processed == 10


def test_opencv_threads_leave_the_cores_of_the_other_lanes_and_are_restored():
    import cv2

    from vio_depth.run.overlap import opencv_threads, overlap_opencv_threads, prefetch_workers

    assert [prefetch_workers(True, c) for c in (1, 2, 3, 16)] == [1, 2, 3, 4]
    assert [prefetch_workers(False, c) for c in (1, 2, 16)] == [1, 1, 1]
    assert [overlap_opencv_threads(prefetch_workers(True, c), c) for c in (1, 2, 3, 16)] == [1, 1, 1, 10]
    before = cv2.getNumThreads()
    with opencv_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before
    with opencv_threads(None):
        assert cv2.getNumThreads() == before


def test_blas_threads_are_limited_for_the_duration_and_restored():
    from threadpoolctl import threadpool_info

    from vio_depth.run.overlap import blas_threads

    def counts():
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    before = counts()
    assert before, "numpy is linked against a BLAS library"
    with blas_threads(1):
        assert counts() == [1] * len(before)
    assert counts() == before
    with blas_threads(None):
        assert counts() == before


def test_torch_threads_are_limited_once_torch_is_loaded_and_restored(monkeypatch):
    torch = pytest.importorskip("torch")
    from vio_depth.run.overlap import TorchThreads

    before = torch.get_num_threads()
    monkeypatch.delitem(sys.modules, "torch")  # torch not loaded yet when the run starts
    with TorchThreads(1) as limit:
        assert torch.get_num_threads() == before
        monkeypatch.setitem(sys.modules, "torch", torch)  # a matcher loads it on its first product
        limit.poll()
        assert torch.get_num_threads() == 1
        limit.poll()
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with TorchThreads(None) as limit:
        limit.poll()
        assert torch.get_num_threads() == before
