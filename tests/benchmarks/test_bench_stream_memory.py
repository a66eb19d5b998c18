"""benchmarks/bench_stream_memory.py's measurement code (the benchmark itself renders a
1000-frame sequence and is run by hand)."""

import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_stream_memory as bsm  # noqa: E402

linux = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")


def test_the_second_half_slope_is_in_kib_per_frame_and_ignores_the_first_half():
    rows = [bsm.Sample(k, 100.0 + (k < 50) * 50 + k / 1024, 0, 0, 0, np.nan, 0) for k in range(10, 101, 10)]
    assert bsm.second_half_slope(rows, "rss") == pytest.approx(1.0)  # 1 KiB a frame from frame 50 on
    assert np.isnan(bsm.second_half_slope(rows[:1], "rss"))


@linux
def test_a_child_process_memory_is_sampled():
    before, _ = bsm.workers_mib()  # other tests may have left children (multiprocessing's resource tracker)
    child = subprocess.Popen([sys.executable, "-c", "import sys; b = bytearray(64 << 20); sys.stdin.read()"],
                             stdin=subprocess.PIPE)
    try:
        for _ in range(100):  # until the child holds its 64 MiB
            rss, peak = bsm.workers_mib()
            if rss - before > 64:
                break
            time.sleep(0.05)
        assert child.pid in bsm.child_pids() and rss - before > 64 and peak >= rss
    finally:
        child.communicate(b"")


def test_measure_samples_every_n_frames_and_takes_the_snapshots_asked_for():
    kept = []
    snapshots = dict.fromkeys([2, 4])
    rows = bsm.measure(5, 2, lambda k: kept.append(np.ones(1 << 15)), snapshots)
    assert [r.frames for r in rows] == [2, 4, 5] and not tracemalloc.is_tracing()
    assert all(r.traced > 0 for r in rows) and rows[-1].traced > rows[0].traced
    lines = bsm.snapshot_diff(snapshots[2], snapshots[4], 2)
    assert "+0.50 MiB" in lines[0] and "test_bench_stream_memory.py" in lines[1]  # two 256 KiB arrays, here
