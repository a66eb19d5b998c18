"""Runners for tests/vio_depth/experiments/test_tasks.py.

Kept in a plain module (not a test file) so that spawned pool workers and Ray workers can
import them: the tests put this folder on sys.path (pool) or PYTHONPATH (Ray).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vio_core.errors import SequenceFormatError
from vio_depth.evaluation import depth_noise
from vio_depth.io import open_sequence


def frame_stats(task) -> dict:
    """Ground-truth depth statistics of some frames, and a seeded depth-noise draw on them.

    settings: frames (list of indices), rel_sigma, seed, optional log (a file to which
    every execution appends one line, to count executions across processes).
    """
    s = task.settings
    if s.get("log"):
        with open(s["log"], "a") as fh:
            fh.write(f"{task.variant} {s.get('frames')}\n")
    seq = open_sequence(task.sequence)
    out = {"frames": len(seq), "nan_becomes_none": float("nan"), "numpy_int": np.int64(3)}
    for i in s.get("frames", [0]):
        gt = seq.frame(i).gt_depth()
        z = gt[gt > 0].astype(np.float64)
        noisy = depth_noise(z, s.get("rel_sigma", 0.1), [s.get("seed", 0), i])
        out[f"frame_{i}"] = {"mean_gt": z.mean(), "mean_noisy": np.nanmean(noisy), "n": z.size}
    return out


def fails_while_flag_exists(task) -> dict:
    """Raises a SequenceFormatError (not picklable by args) while the file settings['flag'] exists."""
    if Path(task.settings["flag"]).exists():
        raise SequenceFormatError("/data/seq/poses.txt", "expected 8 columns, got 7", line=3)
    return frame_stats(task)


def not_jsonable(task) -> dict:
    return {"ok": 1, "bad": object()}
