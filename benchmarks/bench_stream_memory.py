"""Memory of a long ``FrameStream`` (issue 24: "peak memory flat over 1 000 frames").

A robot's depth node pushes frames for hours. This benchmark pushes ``--frames`` frames (default
1 000) of the bundled street sample (640x256, 10 Hz, SIMULATED disparity from its ground-truth
depth, exact rendered poses, ``--poses gt``) into one :class:`~vio_depth.FrameStream`; the 130
frames ping-pong (0..129, 128..1, 0..) so the camera path stays continuous, with increasing
timestamps. Every ``--every`` frames it samples this process's resident memory (``VmRSS``) and
its peak (``VmHWM``), for each matcher (``sift``: today's default; ``klt`` with the edge guard).

Named baseline, in the same run: **the state at frame ``--baseline``** (default 200, after the
keyframe buffer, the rescaler's filter and the caches filled). Criterion per matcher: peak RSS
at the end <= 1.1 x the peak at the baseline frame + 16 MiB (Linux only: ``/proc``). Exits 1
when a criterion fails.

    python benchmarks/bench_stream_memory.py                       # 1000 frames, sift and klt
    python benchmarks/bench_stream_memory.py --frames 300 --matchers klt

The odometry (``--poses vio``) is not covered: no bundled sequence with an IMU is longer than
120 frames, and the rendered samples' trajectories leave their scenes after a few seconds.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_realtime import reset_peak_rss  # noqa: E402
from throughput_data import pingpong  # noqa: E402

from vio_depth import FrameStream, PipelineSettings, open_sequence  # noqa: E402
from vio_depth.disparity import DisparitySettings, create_disparity_source  # noqa: E402

STREET = ROOT / "sample_sequences" / "street"


def rss_mib() -> tuple[float, float] | None:
    """(VmRSS, VmHWM) of this process in MiB, or None off Linux."""
    try:
        with open("/proc/self/status") as f:
            fields = {ln.split(":")[0]: int(ln.split()[1]) for ln in f if ln.startswith(("VmRSS:", "VmHWM:"))}
        return fields["VmRSS"] / 1024, fields["VmHWM"] / 1024
    except (OSError, KeyError, ValueError):
        return None


def run(matcher: str, n: int, every: int, guard: float | None) -> list[tuple[int, float, float, float]]:
    """``[(frames pushed, RSS MiB, peak MiB, seconds so far)]`` every ``every`` frames."""
    seq = open_sequence(STREET)
    disparity = create_disparity_source(DisparitySettings(), seq)
    frames = [seq[i] for i in range(len(seq))]
    images = [f.image() for f in frames]  # 130 x 640x256x3: 64 MiB, loaded before the first sample
    maps = [np.asarray(disparity(f), np.float32) for f in frames]
    settings = PipelineSettings.from_presets(matcher=matcher)
    if guard is not None:
        settings = replace(settings, rescaler=replace(settings.rescaler, max_disparity_spread=guard))
    stream = FrameStream(seq.camera, settings, pose_kind=seq.pose_kind)
    order = pingpong(len(frames), n)
    dt = 1.0 / 10.0
    out = []
    start = time.perf_counter()
    for k, i in enumerate(order):
        stream.push(images[i], maps[i], timestamp=k * dt, T_w_c=frames[i].T_w_c)
        if (k + 1) % every == 0 or k + 1 == n:
            mem = rss_mib()
            out.append((k + 1, *(mem if mem is not None else (np.nan, np.nan)), time.perf_counter() - start))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--baseline", type=int, default=200, help="the frame whose peak is the baseline")
    parser.add_argument("--matchers", default="sift,klt")
    parser.add_argument("--klt-edge-guard", type=float, default=0.1)
    args = parser.parse_args(argv)
    if not (STREET / "sequence.json").exists():
        print("bundled street sample missing: nothing measured")
        return 0
    if args.baseline % args.every or not args.every <= args.baseline < args.frames:
        parser.error("--baseline must be a multiple of --every and below --frames")
    print(f"# machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy "
          f"{np.__version__}; load average {os.getloadavg()[0]:.1f} at start")
    print(f"# street sample ping-ponged to {args.frames} frames, --poses gt, FrameStream; SIMULATED disparity")
    failed = False
    for matcher in [m for m in args.matchers.split(",") if m]:
        guard = args.klt_edge_guard if matcher == "klt" else None
        # each matcher in a fresh process would isolate the peaks; one process keeps it simple:
        # the peak (VmHWM) is reset before each matcher where Linux allows it
        reset_peak_rss()
        rows = run(matcher, args.frames, args.every, guard)
        label = matcher if guard is None else f"{matcher}, guard {guard:g}"
        print(f"\n## {label}\n\n| frames | RSS MiB | peak MiB | seconds |\n|---|---|---|---|")
        for k, rss, peak, sec in rows:
            print(f"| {k} | {rss:.0f} | {peak:.0f} | {sec:.0f} |")
        base = next(p for k, _, p, _ in rows if k == args.baseline)
        end = rows[-1][2]
        ok = end <= 1.1 * base + 16
        failed |= not ok
        print(f"\npeak at frame {rows[-1][0]}: {end:.0f} MiB; at frame {args.baseline} (baseline): {base:.0f} MiB; "
              f"limit 1.1 x baseline + 16 = {1.1 * base + 16:.0f}: **{'PASS' if ok else 'FAIL'}**")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
