"""CachedDisparitySource: each map computed once, read back bit-identical, None remembered."""

import os
import threading

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError
from vio_depth.disparity import CachedDisparitySource, DisparityKind, cache_key
from vio_depth.frame import Frame


class CountingSource:
    kind = DisparityKind.SIMULATED

    def __init__(self):
        self.calls = 0

    def __call__(self, frame):
        self.calls += 1
        if frame.index == 2:
            return None
        rng = np.random.default_rng(frame.index)
        return rng.random((4, 6)).astype(np.float32) / 3.0  # not exactly representable in decimal


def _frame(i):
    return Frame(index=i, timestamp=float(i), stem=f"f{i}", camera=Camera(6, 4, 5.0, 5.0, 3.0, 2.0),
                 T_w_c=np.eye(4), load_image=lambda: np.zeros((4, 6, 3), np.uint8))


def test_maps_are_computed_once_and_read_back_identical(tmp_path):
    src = CountingSource()
    cached = CachedDisparitySource(src, tmp_path, "k1")
    assert cached.kind == DisparityKind.SIMULATED
    first = [cached(_frame(i)) for i in range(3)]
    again = CachedDisparitySource(CountingSource(), tmp_path, "k1")
    second = [again(_frame(i)) for i in range(3)]
    assert src.calls == 3 and again.source.calls == 0 and again.hits == 3
    for a, b in zip(first[:2], second[:2], strict=True):
        assert a.dtype == b.dtype == np.float32 and np.array_equal(a, b)
    assert first[2] is None and second[2] is None
    other = CachedDisparitySource(CountingSource(), tmp_path, "k2")  # another key: computed again
    other(_frame(0))
    assert other.misses == 1


def test_a_damaged_entry_is_recomputed(tmp_path):
    cached = CachedDisparitySource(CountingSource(), tmp_path, "k")
    cached.path_for(_frame(0)).write_bytes(b"not a npy file")
    d = cached(_frame(0))
    assert d.shape == (4, 6) and cached.misses == 1
    assert np.array_equal(np.load(cached.path_for(_frame(0))), d)


def test_keys_are_stable_and_must_be_file_names(tmp_path):
    assert cache_key({"a": 1, "b": [2]}, "x") == cache_key({"b": [2], "a": 1}, "x") != cache_key({"a": 2}, "x")
    with pytest.raises(InputError):
        CachedDisparitySource(CountingSource(), tmp_path, "../up")


def test_a_worker_waits_for_the_map_another_worker_is_computing(tmp_path):
    cached = CachedDisparitySource(CountingSource(), tmp_path, "k", poll=0.01)
    lock = cached.path_for(_frame(1)).with_suffix(".lock")
    lock.touch()  # another worker is computing frame 1

    def other_worker_finishes():
        np.save(cached.path_for(_frame(1)), np.full((4, 6), 7.0, np.float32))
        lock.unlink()

    timer = threading.Timer(0.2, other_worker_finishes)
    timer.start()
    d = cached(_frame(1))
    timer.join()
    assert np.all(d == 7.0) and cached.source.calls == 0 and cached.hits == 1  # read, not recomputed


def test_a_stale_lock_is_ignored(tmp_path):
    cached = CachedDisparitySource(CountingSource(), tmp_path, "k", stale_after=60.0, poll=0.01)
    lock = cached.path_for(_frame(0)).with_suffix(".lock")
    lock.touch()
    os.utime(lock, (0, 0))  # written in 1970: its worker is gone
    assert cached(_frame(0)).shape == (4, 6) and cached.source.calls == 1
    assert lock.exists()  # someone else's lock is left alone
