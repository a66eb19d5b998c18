"""The landmark window's keyframe cost, batch against iSAM2 (``LandmarkSettings.solver``), under
``--poses gt --points landmarks`` with SIFT (issue 24 item 4; docs/benchmarks.md "Incremental
window (iSAM2)").

Runs :func:`bench_landmarks.run_path` (whole sequence, the CLI's defaults) for the paths
``landmarks-batch`` and ``landmarks-isam2``, alternating, ``--repeats`` times, and prints per run:
keyframes, the thread CPU of ``LandmarkWindow.add_keyframe`` (mean / median / p90 ms), of the
graph's ``refine`` (mean ms), the points stage's CPU per frame, the whole run's CPU per frame,
AbsRel and its oracle, wrong frames (status ok, AbsRel > 2 x oracle + 0.02) and how often iSAM2
rebuilt itself after a failed update. All sample sequences are SIMULATED.

    python benchmarks/bench_window_solver.py --datasets street,room --repeats 2
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_landmarks as B  # noqa: E402
from vio_depth import open_sequence  # noqa: E402
from vio_depth.landmarks.graph import WindowGraph  # noqa: E402
from vio_depth.landmarks.isam import IsamGraph  # noqa: E402
from vio_depth.landmarks.window import LandmarkWindow  # noqa: E402


class _Count(logging.Handler):
    def __init__(self):
        super().__init__()
        self.n = 0

    def emit(self, record):
        self.n += 1


def _timed(cls, name: str, out: list) -> None:
    orig = getattr(cls, name)

    def wrapper(self, *args, **kwargs):
        start = time.thread_time()
        try:
            return orig(self, *args, **kwargs)
        finally:
            out.append(time.thread_time() - start)

    setattr(cls, name, wrapper)


def measure(name: str, path: str, data: Path) -> str:
    ds = B.DATASETS[name]
    seq = open_sequence(ds.folder(data))
    n = len(seq) if ds.frames is None else min(ds.frames, len(seq))
    refine, add = [], []
    graph = IsamGraph if path == "landmarks-isam2" else WindowGraph
    saved = (graph.refine, LandmarkWindow.add_keyframe)
    _timed(graph, "refine", refine)
    _timed(LandmarkWindow, "add_keyframe", add)
    count = _Count()
    log = logging.getLogger("vio_depth.landmarks.isam")
    log.setLevel(logging.INFO)
    log.addHandler(count)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            m, frames = B.run_path(ds, seq, n, path, Path(tmp) / path)
    finally:
        graph.refine, LandmarkWindow.add_keyframe = saved
        log.removeHandler(count)
    a, r = 1000 * np.array(add), 1000 * np.array(refine)
    return (f"{name} {path:16s} keyframes {len(a)} | keyframe update CPU ms mean {a.mean():.1f} median "
            f"{np.median(a):.1f} p90 {np.percentile(a, 90):.1f} | refine mean {r.mean():.1f} | points stage CPU "
            f"ms/frame {B.LAST_CPU['points_ms']:.1f} | run CPU s/frame {B.LAST_CPU['run_s']:.3f} | AbsRel "
            f"{m['metrics']['landmarks']['abs_rel']:.5f} oracle {m['metrics']['oracle']['abs_rel']:.5f} | wrong "
            f"{len(B._bad_frames(frames))} | iSAM2 rebuilds {count.n}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default="street,room")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--data", type=Path, default=B.REPO / ".." / "shared" / "data")
    args = parser.parse_args(argv)
    for _ in range(args.repeats):
        for name in args.datasets.split(","):
            for path in ("landmarks-batch", "landmarks-isam2"):
                print(measure(name, path, args.data), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
