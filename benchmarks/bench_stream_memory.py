"""Memory of a long ``FrameStream`` (issue 24: "peak memory flat over 1 000 frames").

A robot's depth node pushes frames for hours. This benchmark pushes ``--frames`` frames (default
1 000) into one :class:`~vio_depth.FrameStream` per matcher (``sift``: today's default; ``klt``
with the edge guard). Every ``--every`` frames it samples this process's resident memory
(``VmRSS``) and its peak (``VmHWM``). ``--poses`` picks the data (comma-separated, default ``gt``):

* ``gt``: the bundled street sample (640x256, 10 Hz, SIMULATED disparity from its ground-truth
  depth, exact rendered poses); its 130 frames ping-pong (0..129, 128..1, 0..) so the camera
  path stays continuous, with increasing timestamps.
* ``vio``: the camera+IMU odometry on a generated ASL sequence of ``--frames`` frames: the room
  walked round its table in a closed loop every 20 s (``generate_asl_sample(trajectory="loop")``,
  :func:`vio_depth.simulate.generate.room_loop_trajectory`), at ``--scale`` of 512x384 (default
  0.5: 256x192), 20 Hz, with its consistent 200 Hz IMU; SIMULATED images, IMU and disparity (an
  affine map ``2 / depth + 0.1`` of the rendered true depth, as ``realtime_data.asl_room``).
  Frames cannot ping-pong under an IMU (the IMU must match the motion), so the sequence is
  rendered at full length, once, into ``--cache`` (outside the repository; 1 000 frames at
  0.5: a few minutes). Each push carries the IMU samples since the previous one (as
  ``bench_realtime.StreamRunner``); the odometry's states per frame (tracking / converging /
  lost ...), the frames with depth and the pose error against the ground truth (per session,
  positions aligned with a rigid transform) are reported.

  ``--points vio`` fits the odometry's own landmarks; ``--backends inline,process:6`` runs a
  row per landmark-window backend (``VioSettings.backend``): with ``process`` the worker
  process's ``VmRSS`` / ``VmHWM`` are sampled too (``/proc/<pid>/status`` of this process's
  children, summed: the worker and multiprocessing's resource tracker, 13 MiB). ``--history-frames`` sets ``VioSettings.history_frames`` (the odometry's pose
  history, bounded by it: the part of a vio row's memory that still grows until that many
  frames passed).

Named baseline, in the same run: **the state at frame ``--baseline``** (default 200, after the
keyframe buffer, the rescaler's filter and the caches filled). Criterion per row: peak RSS at
the end (plus the worker's peak) <= 1.1 x the same at the baseline frame + 16 MiB (Linux only:
``/proc``). Exits 1 when a criterion fails. Each row also prints the least-squares slope of the
second half (KiB per frame). ``--tracemalloc A,B`` traces Python's allocations (about 30 x
slower; this process only, not a worker) and lists the allocation sites that grew most
between frames A and B.

    python benchmarks/bench_stream_memory.py                       # 1000 frames, gt, sift and klt (minutes)
    python benchmarks/bench_stream_memory.py --frames 300 --matchers klt
    python benchmarks/bench_stream_memory.py --poses vio --matchers klt --points vio \
        --backends inline,process:6                                # renders the loop once (minutes)
    python benchmarks/bench_stream_memory.py --poses vio --matchers klt --points vio --tracemalloc 300,900
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_realtime import reset_peak_rss  # noqa: E402
from throughput_data import pingpong  # noqa: E402

from vio_depth import FrameStream, PipelineSettings, open_sequence  # noqa: E402
from vio_core.errors import VioDepthError  # noqa: E402
from vio_depth.disparity import DisparitySettings, create_disparity_source  # noqa: E402
from vio_depth.landmarks.settings import WindowBackendSettings  # noqa: E402

STREET = ROOT / "sample_sequences" / "street"
DEFAULT_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vio-depth" / "bench_stream_memory"
LOOP_MARKER = "prepared.json"


def rss_mib(pid: int | str = "self") -> tuple[float, float] | None:
    """(VmRSS, VmHWM) of process ``pid`` (default this one) in MiB, or None off Linux or when gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            fields = {ln.split(":")[0]: int(ln.split()[1]) for ln in f if ln.startswith(("VmRSS:", "VmHWM:"))}
        return fields["VmRSS"] / 1024, fields["VmHWM"] / 1024
    except (OSError, KeyError, ValueError):
        return None


def child_pids() -> list[int]:
    """This process's live children (the landmark window's worker with ``--backend process``; Linux)."""
    me = os.getpid()
    try:
        with open(f"/proc/{me}/task/{me}/children") as f:
            return [int(p) for p in f.read().split()]
    except (OSError, ValueError):
        return []


def workers_mib() -> tuple[float, float]:
    """(sum of VmRSS, sum of VmHWM) over this process's children in MiB (0, 0 with none)."""
    mems = [m for m in map(rss_mib, child_pids()) if m is not None]
    return sum(m[0] for m in mems), sum(m[1] for m in mems)


def pipeline_settings(matcher: str, guard: float | None, backend: WindowBackendSettings | None = None,
                      history_frames: int | None = None, **presets) -> PipelineSettings:
    settings = PipelineSettings.from_presets(matcher=matcher, **presets)
    if guard is not None:  # --edge-guard: corners on depth edges are not fitted
        settings = replace(settings, rescaler=replace(settings.rescaler, max_disparity_spread=guard))
    if backend is not None:  # --backend process:LAG: the landmark window in a worker
        settings = replace(settings, poses=replace(settings.poses, backend=backend))
    if history_frames is not None:  # --history-frames: the odometry's pose history bound
        settings = replace(settings, poses=replace(settings.poses, history_frames=history_frames))
    return settings


def parse_backend(text: str) -> WindowBackendSettings:
    """``inline`` or ``process[:LAG]`` (argparse type)."""
    kind, _, lag = text.partition(":")
    try:
        return WindowBackendSettings(kind, int(lag)) if lag else WindowBackendSettings(kind)
    except (VioDepthError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"--backend {text!r}: {exc} (inline, process or process:LAG)") from None


class Sample(NamedTuple):
    """One checkpoint: frames pushed, this process's RSS / peak and its children's (MiB), the
    Python heap tracemalloc traces (MiB, NaN when off) and the seconds so far."""

    frames: int
    rss: float
    peak: float
    worker_rss: float
    worker_peak: float
    traced: float
    seconds: float


def measure(n: int, every: int, push: Callable[[int], None],
            snapshots: dict[int, "tracemalloc.Snapshot"] | None = None) -> list[Sample]:
    """``push(k)`` for k < n, a :class:`Sample` every ``every`` frames. With ``snapshots`` (keys:
    frame counts) tracemalloc runs and its snapshot after each of those frames is stored there."""
    out = []
    if snapshots is not None:
        tracemalloc.start(16)
    start = time.perf_counter()
    try:
        for k in range(n):
            push(k)
            if snapshots is not None and k + 1 in snapshots:
                snapshots[k + 1] = tracemalloc.take_snapshot()
            if (k + 1) % every == 0 or k + 1 == n:
                mem = rss_mib() or (np.nan, np.nan)
                traced = tracemalloc.get_traced_memory()[0] / 2 ** 20 if snapshots is not None else np.nan
                out.append(Sample(k + 1, *mem, *workers_mib(), traced, time.perf_counter() - start))
    finally:
        if snapshots is not None:
            tracemalloc.stop()
    return out


def second_half_slope(rows: list[Sample], field: str) -> float:
    """KiB per frame of ``field`` over the second half of the run (least squares over its checkpoints)."""
    half = [r for r in rows if r.frames >= rows[-1].frames / 2]
    if len(half) < 2:
        return np.nan
    x = np.array([r.frames for r in half], float)
    return float(np.polyfit(x, np.array([getattr(r, field) for r in half], float), 1)[0] * 1024)


def snapshot_diff(a: "tracemalloc.Snapshot", b: "tracemalloc.Snapshot", frames: int, top: int = 12) -> list[str]:
    """The ``top`` allocation sites that grew most from snapshot ``a`` to ``b`` (``frames`` apart),
    each with its growth per frame and its innermost package frame."""
    keep = [tracemalloc.Filter(False, tracemalloc.__file__),
            tracemalloc.Filter(False, "<frozen importlib._bootstrap*>")]
    stats = b.filter_traces(keep).compare_to(a.filter_traces(keep), "traceback")
    total = sum(s.size_diff for s in stats)
    lines = [f"tracemalloc growth over {frames} frames: {total / 2 ** 20:+.2f} MiB ({total / frames / 1024:+.2f} KiB "
             "per frame); the sites that grew most:"]
    for s in sorted(stats, key=lambda s: -s.size_diff)[:top]:
        ours = [f for f in s.traceback if "vio_depth" in f.filename or "vio_core" in f.filename] or list(s.traceback)
        where = " <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in ours[-3:][::-1])
        lines.append(f"{s.size_diff / 1024:+9.1f} KiB ({s.count_diff:+d} blocks, "
                     f"{s.size_diff / frames:+.0f} B/frame) {where}")
    return lines


# ----------------------------------------------------------------------------- --poses gt: street ping-pong
def street_gt(matcher: str, n: int, guard: float | None) -> Callable[[int], None]:
    """The push of frame k of the street sample ping-ponged to ``n`` frames (``--poses gt``)."""
    seq = open_sequence(STREET)
    disparity = create_disparity_source(DisparitySettings(), seq)
    frames = [seq[i] for i in range(len(seq))]
    images = [f.image() for f in frames]  # 130 x 640x256x3: 64 MiB, loaded before the first sample
    maps = [np.asarray(disparity(f), np.float32) for f in frames]
    stream = FrameStream(seq.camera, pipeline_settings(matcher, guard), pose_kind=seq.pose_kind)
    order = pingpong(len(frames), n)

    def push(k: int) -> None:
        i = order[k]
        stream.push(images[i], maps[i], timestamp=k / 10.0, T_w_c=frames[i].T_w_c)

    return push


# ----------------------------------------------------------------------------- --poses vio: the room loop
def prepare_loop(cache: Path, n: int, scale: float, log=print) -> Path:
    """The room loop (SIMULATED) of ``n`` frames at ``scale`` with its true depth, rendered into
    ``cache`` on first use (a marker file says what is there)."""
    from vio_depth.simulate.asl import generate_asl_sample

    folder = cache / f"room_loop_{n}_x{scale:g}"
    want = {"sample": "room", "trajectory": "loop", "frames": n, "scale": scale, "layout": 1}
    try:
        if json.loads((folder / LOOP_MARKER).read_text()) == want:
            return folder
    except (OSError, ValueError):
        pass
    log(f"# rendering the room loop ({n} frames at x{scale:g}) into {folder} (once; minutes)")
    start = time.perf_counter()
    generate_asl_sample(folder, sample="room", n_frames=n, scale=scale, trajectory="loop", depth_dir=folder / "depth")
    (folder / LOOP_MARKER).write_text(json.dumps(want))
    log(f"# rendered in {time.perf_counter() - start:.0f} s")
    return folder


class LoopVio:
    """Pushes frame k of the rendered room loop with the IMU samples since the previous push
    (``--poses vio``) and keeps what the odometry said: per frame its state, whether the frame
    got depth, and its position when posed (a few numbers a frame)."""

    def __init__(self, folder: Path, matcher: str, guard: float | None, points: str | None = None,
                 backend: WindowBackendSettings | None = None, history_frames: int | None = None,
                 preset: str = "vio_offline"):
        self.folder = folder
        self.seq = open_sequence(folder)
        self.frames = [self.seq[i] for i in range(len(self.seq))]
        self.imu = self.seq.imu
        settings = pipeline_settings(matcher, guard, backend, history_frames, poses=preset, pairing="indoor",
                                     points=points)
        self.stream = FrameStream(self.seq.camera, settings, imu_calibration=self.imu, pose_kind=self.seq.pose_kind)
        self.imu_done = -np.inf
        n = len(self.frames)
        self.status = np.full(n, "", dtype=object)
        self.has_depth = np.zeros(n, bool)
        self.position = np.full((n, 3), np.nan)
        self.frame_status: dict[str, int] = {}

    def __call__(self, k: int) -> None:
        frame = self.frames[k]
        depth = np.load(self.folder / "depth" / f"{frame.stem}.npy")
        disparity = np.where(depth > 0, 2.0 / np.maximum(depth, 1e-6) + 0.1, 0.0).astype(np.float32)  # SIMULATED
        t = frame.timestamp
        new = (self.imu.t > self.imu_done) & (self.imu.t <= t)
        self.imu_done = t
        result = self.stream.push(frame.image(), disparity, timestamp=t,
                                  imu=(self.imu.t[new], self.imu.gyro[new], self.imu.accel[new]))
        pose = result.frame_pose
        self.status[k] = "none" if pose is None or pose.status is None else pose.status.value
        self.has_depth[k] = result.has_depth
        self.frame_status[result.status.value] = self.frame_status.get(result.status.value, 0) + 1
        if pose is not None and pose.ok and pose.T_w_c is not None:
            self.position[k] = pose.T_w_c[:3, 3]

    def report(self, n: int) -> list[str]:
        """Lines: states per frame (run-length), frames with depth, pose error per session."""
        from vio_depth.evaluation import umeyama_alignment

        status = self.status[:n]
        names, counts = np.unique(status, return_counts=True)
        lines = ["odometry states over the run: " + ", ".join(f"{a} {b}" for a, b in zip(names, counts))
                 + f"; frames with depth: {int(self.has_depth[:n].sum())}/{n} (frame statuses: "
                 + ", ".join(f"{a} {b}" for a, b in sorted(self.frame_status.items(), key=lambda x: -x[1])) + ")"]
        runs, first = [], 0
        for k in range(1, n + 1):
            if k == n or status[k] != status[first]:
                runs.append(f"{status[first]} {first}-{k - 1}")
                first = k
        lines.append("state runs (frames): " + ", ".join(runs[:40]) + (" ..." if len(runs) > 40 else ""))
        # a session starts at a frame posed after one that was not initialised (initialising / lost)
        truth = np.stack([f.T_w_c[:3, 3] for f in self.frames[:n]])
        unposed = np.isin(status, ["initialising", "lost", "none"])
        session = np.cumsum(np.r_[True, unposed[:-1]] & ~unposed) * ~unposed
        for s in np.unique(session[session > 0]):
            idx = np.flatnonzero((session == s) & np.isfinite(self.position[:n, 0]))
            if len(idx) < 3:
                continue
            R, tr, _ = umeyama_alignment(self.position[idx], truth[idx])
            err = np.linalg.norm(self.position[idx] @ R.T + tr - truth[idx], axis=1)
            last = err[idx >= idx[-1] - 99]
            lines.append(f"session {s}: frames {idx[0]}-{idx[-1]}, {len(idx)} posed online; position error after a "
                         f"rigid alignment: RMSE {np.sqrt(np.mean(err ** 2)) * 100:.1f} cm, max "
                         f"{err.max() * 100:.1f} cm, last 100 frames RMSE {np.sqrt(np.mean(last ** 2)) * 100:.1f} cm; "
                         f"path {np.linalg.norm(np.diff(truth[idx], axis=0), axis=1).sum():.1f} m")
        return lines


# ----------------------------------------------------------------------------- main
def print_row(label: str, rows: list[Sample], baseline: int, worker: bool, traced: bool) -> bool:
    """The row's table, its second-half slopes and its criterion; True when it passes."""
    cols = ["frames", "RSS MiB", "peak MiB"] + ["worker RSS MiB", "worker peak MiB"] * worker \
        + ["traced MiB"] * traced + ["seconds"]
    print(f"\n## {label}\n\n| {' | '.join(cols)} |\n|{'---|' * len(cols)}")
    for r in rows:
        cells = [f"{r.frames}", f"{r.rss:.0f}", f"{r.peak:.0f}"] \
            + [f"{r.worker_rss:.0f}", f"{r.worker_peak:.0f}"] * worker + [f"{r.traced:.1f}"] * traced \
            + [f"{r.seconds:.0f}"]
        print(f"| {' | '.join(cells)} |")
    slopes = [("RSS", "rss")] + [("worker RSS", "worker_rss")] * worker + [("traced", "traced")] * traced
    print("\nsecond half (frames >= " + f"{rows[-1].frames // 2}), least-squares slope: "
          + ", ".join(f"{name} {second_half_slope(rows, field):+.1f} KiB/frame" for name, field in slopes))
    # a process row's criterion counts the children too (the worker and multiprocessing's resource
    # tracker): their peaks plus ours bound the peak of all from above. An inline row after a process
    # row still has the tracker (13 MiB, idle): not counted
    base_row = next(r for r in rows if r.frames == baseline)
    base, end = base_row.peak + worker * base_row.worker_peak, rows[-1].peak + worker * rows[-1].worker_peak
    ok = end <= 1.1 * base + 16
    what = "peak (+ worker peak)" if worker else "peak"
    print(f"{what} at frame {rows[-1].frames}: {end:.0f} MiB; at frame {baseline} (baseline): {base:.0f} MiB; "
          f"limit 1.1 x baseline + 16 = {1.1 * base + 16:.0f}: **{'PASS' if ok else 'FAIL'}**")
    return ok


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--baseline", type=int, default=200, help="the frame whose peak is the baseline")
    parser.add_argument("--matchers", default="sift,klt")
    parser.add_argument("--klt-edge-guard", type=float, default=0.1)
    parser.add_argument("--poses", default="gt", help="comma-separated: gt (street ping-pong), vio (the room loop)")
    parser.add_argument("--points", default=None,
                        help="vio rows: the points preset (e.g. vio; default: the pipeline's)")
    parser.add_argument("--backends", default="inline", type=lambda t: [parse_backend(b) for b in t.split(",") if b],
                        help="vio rows, comma-separated: inline, process or process:LAG (the landmark window in a "
                             "worker; its memory is sampled too)")
    parser.add_argument("--vio-preset", default="vio_offline", choices=("vio_offline", "vio", "vio_realtime"),
                        help="vio rows: the pose preset (vio_offline: vio's settings until 2026-12-07, batch window; "
                             "vio / vio_realtime, its former name: iSAM2 window, bridges when learnt better; "
                             "--backends still sets where the window runs)")
    parser.add_argument("--history-frames", type=int, default=None,
                        help="vio rows: VioSettings.history_frames (the poses remembered; default 20 000)")
    parser.add_argument("--tracemalloc", default="", metavar="A,B",
                        help="trace Python allocations (slow) and list the sites that grew most between frames A and B")
    parser.add_argument("--scale", type=float, default=0.5, help="image size factor of the room loop (vio)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help="where the room loop is rendered (vio)")
    args = parser.parse_args(argv)
    poses = [p for p in args.poses.split(",") if p]
    if not poses or not set(poses) <= {"gt", "vio"}:
        parser.error(f"unknown --poses {args.poses!r} (valid: gt, vio)")
    if args.baseline % args.every or not args.every <= args.baseline < args.frames:
        parser.error("--baseline must be a multiple of --every and below --frames")
    trace = [int(t) for t in args.tracemalloc.split(",") if t.strip()]
    if trace and not (len(trace) == 2 and 0 < trace[0] < trace[1] <= args.frames):
        parser.error("--tracemalloc wants two frame counts A,B with 0 < A < B <= --frames")
    print(f"# machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy "
          f"{np.__version__}; load average {os.getloadavg()[0]:.1f} at start; "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", flush=True)
    failed = False
    for pose in poses:
        if pose == "gt":
            if not (STREET / "sequence.json").exists():
                print("bundled street sample missing: --poses gt not measured")
                continue
            print(f"# street sample ping-ponged to {args.frames} frames, --poses gt, FrameStream; SIMULATED disparity")
        else:
            folder = prepare_loop(args.cache, args.frames, args.scale, log=lambda m: print(m, flush=True))
            print(f"# room loop, {args.frames} frames at x{args.scale:g}, 20 Hz, --poses vio --pairing indoor"
                  f"{'' if args.points is None else ' --points ' + args.points}, FrameStream; SIMULATED images, "
                  "200 Hz IMU and disparity (2 / true depth + 0.1)", flush=True)
        for matcher in [m for m in args.matchers.split(",") if m]:
            guard = args.klt_edge_guard if matcher == "klt" else None
            for backend in args.backends if pose == "vio" else [None]:
                # each row in a fresh process would isolate the peaks; one process keeps it simple:
                # the peak (VmHWM) is reset before each row where Linux allows it
                reset_peak_rss()
                push = street_gt(matcher, args.frames, guard) if pose == "gt" else \
                    LoopVio(folder, matcher, guard, args.points, backend, args.history_frames, args.vio_preset)
                snapshots = dict.fromkeys(trace) if trace else None
                rows = measure(args.frames, args.every, push, snapshots)
                label = f"--poses {args.vio_preset if pose == 'vio' else pose}, {matcher}" \
                    + ("" if guard is None else f", guard {guard:g}") \
                    + ("" if backend is None else f", backend {backend.kind}"
                       + (f" (lag {backend.lag_frames})" if backend.kind == "process" else "")) \
                    + ("" if args.history_frames is None or pose == "gt" else f", history_frames {args.history_frames}")
                failed |= not print_row(label, rows, args.baseline, backend is not None and backend.kind == "process",
                                        bool(trace))
                if isinstance(push, LoopVio):
                    for line in push.report(args.frames):
                        print(f"- {line}")
                if trace:
                    print()
                    for line in snapshot_diff(snapshots[trace[0]], snapshots[trace[1]], trace[1] - trace[0]):
                        print(f"    {line}")
                sys.stdout.flush()
                del push, snapshots
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
