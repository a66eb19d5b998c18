"""The odometry's per-frame cost on the generated ASL sample, against a baseline revision in the
same run (issue 24: the landmark window and its smoother cheap per frame).

The generated ASL sample (``realtime_data.asl_room``: room, 80 frames, 512x384, SIMULATED
images, 200 Hz IMU and disparity) is pushed frame by frame through ``FrameStream`` with
``--poses vio`` (as ``bench_realtime.py``, mode afap), once with this checkout's code and once
with a baseline revision's (``--baseline-rev``, default ``main``; a temporary git worktree,
run in a subprocess with ``PYTHONPATH`` set to it), alternating ``--repeats`` times.

Columns, per run: the ``poses`` stage's wall milliseconds per frame (mean, p90, p99: the
odometry -- tracking, keyframe window updates; what a loaded machine inflates), the same
stage's **CPU** milliseconds (``time.thread_time`` around ``VioEstimator.process``; gtsam runs
in the calling thread: robust to other jobs on the machine), frames posed live, the ATE RMSE
of those live poses against the rendered truth (SE(3) alignment, metres) and the mean dense
AbsRel over the frames with depth (depth capped at 10 m).

    python benchmarks/bench_window_cost.py                       # this checkout against main
    python benchmarks/bench_window_cost.py --baseline-rev af70499 --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def measure(cache: Path) -> dict:
    """One run of this process's code (``sys.path`` decides which checkout) on the ASL sample."""
    import numpy as np

    import realtime_data as data
    from bench_realtime import StreamRunner
    from vio_depth import open_sequence
    from vio_depth.evaluation.metrics import compute_metrics
    from vio_depth.vio import VioEstimator

    ds = data.asl_room(cache)
    seq = open_sequence(cache / "asl_room")
    truth = np.stack([seq[i].T_w_c for i in range(len(seq))])
    cpu: list[float] = []
    process = VioEstimator.process

    def timed(self, *args, **kwargs):
        start = time.thread_time()
        out = process(self, *args, **kwargs)
        cpu.append(time.thread_time() - start)
        return out

    VioEstimator.process = timed
    runner = StreamRunner(ds)
    posed, absrel = {}, []
    push = runner.stream.push

    def recorded(image, disparity, **kwargs):
        res = push(image, disparity, **kwargs)
        if res.frame_pose is not None and res.frame_pose.T_w_c is not None:
            posed[res.frame] = np.asarray(res.frame_pose.T_w_c)
        if res.depth is not None:  # the sample's SIMULATED disparity is 2 / depth + 0.1
            gt = np.where(disparity > 0.1 + 1e-6, 2.0 / np.maximum(disparity - 0.1, 1e-6), 0.0)
            absrel.append(compute_metrics(res.depth, gt, 1e-3, 10.0).abs_rel)
        return res

    runner.stream.push = recorded
    for i in range(len(ds)):
        runner(i)
    wall = 1000 * np.array([t.get("poses", 0.0) for t in runner.timings])
    cpu_ms = 1000 * np.array(cpu)
    ids = sorted(posed)
    P, G = np.stack([posed[i][:3, 3] for i in ids]), truth[ids, :3, 3]
    U, _, Vt = np.linalg.svd((G - G.mean(0)).T @ (P - P.mean(0)))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    ate = float(np.sqrt(np.mean(np.sum((G - G.mean(0) - (P - P.mean(0)) @ R.T) ** 2, axis=1))))
    return {"frames": len(ds), "posed": len(ids), "wall": [float(wall.mean()), *np.percentile(wall, [90, 99])],
            "cpu": [float(cpu_ms.mean()), *np.percentile(cpu_ms, [90, 99])], "ate_m": ate,
            "absrel": float(np.mean(absrel)) if absrel else float("nan")}


def run_checkout(code: Path, cache: Path) -> dict:
    """:func:`measure` in a subprocess with ``code``'s packages first on the path."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", str(code), "--cache", str(cache)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-rev", default="main")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                        / "vio-depth" / "bench_realtime")
    parser.add_argument("--measure", type=Path, help=argparse.SUPPRESS)  # internal: one run of that checkout
    args = parser.parse_args(argv)
    if args.measure is not None:
        sys.path[:0] = [str(args.measure), str(args.measure / "benchmarks")]
        print(json.dumps(measure(args.cache)))
        return 0
    sys.path.insert(0, str(REPO / "benchmarks"))
    from baseline_checkout import baseline_checkout

    rows = []
    with tempfile.TemporaryDirectory() as tmp, baseline_checkout(args.baseline_rev, Path(tmp) / "baseline") as base:
        for k in range(args.repeats):
            for name, code in ((f"baseline {args.baseline_rev}", base), ("this checkout", REPO)):
                rows.append((name, k + 1, run_checkout(code, args.cache)))
    print("| code | run | frames posed | poses ms mean | p90 | p99 | odometry CPU ms mean | p90 | p99 | ATE m "
          "| AbsRel |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, k, r in rows:
        w, c = r["wall"], r["cpu"]
        print(f"| {name} | {k} | {r['posed']}/{r['frames']} | {w[0]:.0f} | {w[1]:.0f} | {w[2]:.0f} | {c[0]:.0f} | "
              f"{c[1]:.0f} | {c[2]:.0f} | {r['ate_m']:.5f} | {r['absrel']:.5f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
