"""Real time on the robot (issue 24): a recorded sequence streamed through ``FrameStream`` at its
camera rate -- per-frame latency, sustained frames/s, dropped and late frames, per-stage time --
against bare OpenCV SIFT and bare KLT tracking on the same frames, in the same run.

**Replay.** Frame ``i`` *arrives* at ``(t_i - t_0) / rate_scale`` seconds (``t``: the recorded
frame timestamps; ``--rate-scale 2`` plays twice as fast). One consumer -- the pipeline, as a
robot's depth node runs it -- takes frames from a **bounded input queue of ``--queue-size``
frames (default 1) that drops the oldest waiting frame when a new one arrives into a full
queue**: a robot wants the newest depth, not a growing backlog. A dropped frame is never
pushed, but its IMU samples are (every push carries all samples since the previous push, up
to its own timestamp). The clock is *virtual*: the pipeline's time per push is measured with
``perf_counter`` and advances the clock; while the queue is empty the clock jumps to the next
arrival instead of sleeping (the same schedule as a real-time replay with an instantaneous
producer, without waiting the recording's duration). Loading and decoding a frame (image and
disparity file) is not timed: a camera driver delivers decoded images.

* **latency** of a frame: its arrival to its result (the depth map, when it has one) --
  queue wait plus processing; p50 / p90 / p99 over the processed frames (with a few dozen
  frames, p99 is close to the maximum).
* **p99 after start**: the same over the frames after the first one with a pose (the
  odometry's initialisation, a one-off of about a second, excluded); the verdict uses the
  whole run's p99 and prints this one beside it.
* **late**: a processed frame whose result came after the next frame's arrival.
* **dropped**: a frame the queue discarded; **dropped after start**: those that arrived after
  the first posed frame's result was out (the start-up -- the odometry's initialisation and its
  first window, taken over from the worker once -- excluded, as for the p99 after start).
* **frames/s** (sustained): processed frames / (last result - first arrival). At the recorded
  rate it cannot exceed the camera rate; ``afap`` shows the capacity.
* mode ``afap`` (as fast as possible): frame ``i + 1`` arrives when frame ``i``'s result is
  out: no queue wait, no drop; latency = processing time.
* mode ``prefetch`` (as fast as possible, overlapped): frames are handed to
  ``FrameStream.submit`` with ``prefetch=2`` (two threads extract features ahead while the
  stream's thread matches, triangulates and fits earlier frames), at most ``PREFETCH_WINDOW``
  frames in flight; frame ``i + PREFETCH_WINDOW`` arrives when frame ``i``'s result is out.
  OpenCV, BLAS and torch run one thread each during the row, as in the CLI run's overlap
  (:mod:`vio_depth.run.overlap`). Latency = arrival to result (includes waiting behind the
  frames in flight). The results equal ``afap``'s (tests/vio_depth/pipeline/test_stream.py).

**Per stage**: mean ms of the pipeline's own stage timings (``FrameResult.timings``: image,
disparity, features, poses -- the odometry --, points with its matching and triangulation,
fit, depth); ``other``: the push's measured time minus those stages (input checks, stream
bookkeeping). In mode ``prefetch`` the features were extracted in the prefetch
threads, beside the other stages, and ``total`` is the latency (arrival to result), so
``other`` there is mostly the wait behind the frames in flight. The depth network is excluded:
disparity comes from files or memory.

**Baselines** (mode ``afap``, same frames, RGB -> grey included): **bare SIFT** --
``cv2.SIFT_create`` with the project's ``matchers.SiftSettings`` (4000 features, contrast
0.04, edge 10, 3 layers, sigma 1.6), ``detectAndCompute`` per frame; **bare KLT** --
``cv2.goodFeaturesToTrack`` (300 corners, quality 0.01, 20 px apart) tracked frame to frame
with ``cv2.calcOpticalFlowPyrLK`` (21x21 window, 3 pyramid levels), topped up with new corners
away from the tracks when fewer than 200 survive (as VINS-Mono / OpenVINS front ends do).

**Peak RSS**: ``VmHWM`` of this process, reset (``/proc/self/clear_refs``) before each row, so a
row's figure is that row's own peak (the pipeline plus one frame; Linux; ``-`` elsewhere).

Before each pipeline row an untimed stream of ``--warmup`` frames runs (lazy imports, caches).

Verdict (issue 24's targets): ``--poses vio`` on 752x480 (EuRoC): ``afap`` >= 20 frames/s, no
frame dropped after the start at the recorded rate (until 2026-12-07 late: none at all) and p99
latency over all frames <= 100 ms there (the same figures are printed,
as indicative, for the 512x384 ASL sample); ``--poses gt`` on 1242x375:
``afap`` (and ``prefetch``) frames/s >= 0.8 x bare SIFT's (the stream's push, no output writing:
``bench_throughput.py`` times the whole CLI run).

**Accuracy** (rendered ASL datasets, which carry the truth): ``ATE mm`` -- the odometry's live
poses against the true ones after an SE(3) alignment (RMSE of the positions); ``AbsRel`` -- the
mean over the frames with depth of the depth against the true depth behind the SIMULATED
disparity (capped at 10 m). A vio row's verdict also requires its ATE within 10 % and its
AbsRel within 5 % of the reference configuration's (``vio_offline``: sift, ``--points sfm``, the
inline window -- ``--poses vio`` until 2026-12-07, what issue 24's clause compares with) ``afap`` row
of the same dataset in the same run, when that row was measured. The rows without
``--pose-presets`` build on ``vio_offline``'s settings.

**Where the odometry's window runs** (``--vio-backends inline,process``, ``--vio-lag N``,
``--vio-when-ready``): ``inline`` (the default: a keyframe's frame waits for the window's
update) or ``process`` (the window in a worker process, :mod:`vio_depth.landmarks.backend`;
its update is taken over N frames after the keyframe). With a worker, recorded-rate rows run
on the wall clock (``replay(wall_clock=True)``: the worker computes while the consumer waits
for the next frame) and the worker's start-up is inside the row (the odometry starts with the
first frame). Such rows decode every frame before the replay and score the depth after it
(:meth:`StreamRunner.preload`; before 2026-12-07 decoding, 8 ms a 752x564 frame, and scoring,
32 ms, ran in the replay's wall time: they slowed the recorded-rate rows and gave the worker time
in both modes); their peak RSS leaves the preloaded frames and kept depth maps out.

**Points under vio** (``--vio-points sfm,vio``): the ``vio`` datasets' rows once per points
source -- ``sfm`` (two-view pairs matched and triangulated again; the default) and ``vio`` (the
odometry's own landmarks and covariances, nothing matched twice; issue 24, item 5).

    python benchmarks/bench_realtime.py                                  # every dataset (renders once)
    python benchmarks/bench_realtime.py --datasets asl_room,euroc --matchers klt --vio-points sfm,vio
    python benchmarks/bench_realtime.py --datasets asl_loop --matchers klt --vio-points vio --modes realtime,afap
    python benchmarks/bench_realtime.py --datasets euroc,kitti_tiny --max-frames 40 --no-baselines
    python benchmarks/bench_realtime.py --datasets asl_room,euroc --matchers klt --vio-points vio \
        --vio-backends inline,process --vio-lag 6 --modes realtime,afap
    python benchmarks/bench_realtime.py --datasets asl_loop --matchers klt --vio-backends process --vio-lag 3 \
        --no-baselines --vio-set "" --vio-set "solver='isam2';bridge_every_update=False"   # settings A/B

``--vio-set`` (repeatable, one row set each) replaces fields of the odometry's settings
(``VioSettings``) or of its window (``LandmarkSettings``) in the vio rows; a row with any is
not the reference row of the accuracy comparison.

**The CLI's pose presets** (``--pose-presets vio_offline,vio``): the vio datasets' rows are then
one set per named ``--poses`` preset, each exactly as ``vio-depth run --poses NAME`` builds it
(its settings, its default matcher and points: sift and two-view for ``vio_offline``, klt and the
odometry's own landmarks for ``vio``), times ``--vio-points`` (when given) and ``--modes``;
``--matchers``, ``--vio-backends``, ``--vio-lag`` and ``--vio-set`` shape only the other rows.
``vio_offline`` with ``--points sfm`` is the reference row::

    python benchmarks/bench_realtime.py --datasets asl_loop,asl_room,euroc --pose-presets vio_offline,vio \
        --modes afap,realtime --no-baselines
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import gc
import itertools
import os
import platform
import sys
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]  # measure this checkout's code

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import realtime_data as data  # noqa: E402

from matchers import MATCHER_PRESETS, SiftSettings  # noqa: E402
from vio_depth import FrameStream, PipelineSettings  # noqa: E402
from vio_depth.evaluation import CameraTrajectory, absolute_trajectory_error  # noqa: E402
from vio_depth.evaluation.metrics import compute_metrics  # noqa: E402
from vio_depth.landmarks import WindowBackendSettings  # noqa: E402
from vio_depth.pipeline import POSE_PRESETS, default_matcher_preset, default_points_spec  # noqa: E402
from vio_depth.pipeline.result import PIPELINE_STAGES  # noqa: E402
from vio_depth.run.overlap import TorchThreads, blas_threads, opencv_threads  # noqa: E402
from vio_depth.vio import VioSettings  # noqa: E402

DEFAULT_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vio-depth" / "bench_realtime"
#: stage columns of the per-stage table (``matching`` and ``triangulation`` are parts of ``points``)
STAGES = (*PIPELINE_STAGES, "matching", "triangulation")
KLT_MAX, KLT_MIN, KLT_SPACING = 300, 200, 20
#: mode ``prefetch``: extraction threads and frames in flight
PREFETCH_THREADS, PREFETCH_WINDOW = 2, 3
#: depth cap of the accuracy column's AbsRel (the rendered ASL rooms are under 7 m deep)
ACCURACY_MAX_DEPTH_M = 10.0
#: issue 24: the fast configuration's ATE within 10 % and AbsRel within 5 % of the reference (vio_offline)
ATE_TOLERANCE, ABS_REL_TOLERANCE = 0.10, 0.05


# ----------------------------------------------------------------------------- replay and its accounting
@dataclass
class Replay:
    """What a replay did. Times in seconds on the replay's clock (first arrival = 0).

    Attributes:
        arrivals: (N,) arrival time of every frame.
        processed: indices of the processed frames, in order; ``starts`` / ``finishes``: when
            each one's processing began and its result came out.
        dropped: indices of the frames the queue discarded.
        afap: frames arrived when the previous result came out (no queue).
    """

    arrivals: np.ndarray
    processed: list[int] = field(default_factory=list)
    starts: list[float] = field(default_factory=list)
    finishes: list[float] = field(default_factory=list)
    dropped: list[int] = field(default_factory=list)
    afap: bool = False

    @property
    def latencies(self) -> np.ndarray:
        """(P,) seconds from arrival to result of every processed frame."""
        return np.asarray(self.finishes) - self.arrivals[self.processed]

    @property
    def late(self) -> int:
        """Processed frames whose result came after the next frame's arrival (0 in ``afap`` mode)."""
        if self.afap:
            return 0
        n = len(self.arrivals)
        return sum(1 for i, f in zip(self.processed, self.finishes) if i + 1 < n and f > self.arrivals[i + 1])

    @property
    def fps(self) -> float:
        """Sustained frames per second: processed frames / (last result - first arrival)."""
        span = self.finishes[-1] - self.arrivals[0] if self.finishes else 0.0
        return len(self.processed) / span if span > 0 else float("nan")


def replay(timestamps: np.ndarray, process: Callable[[int], float], *, rate_scale: float | None = 1.0,
           queue_size: int = 1, wall_clock: bool = False) -> Replay:
    """Stream frames through ``process`` (``process(i)`` handles frame ``i`` and returns the
    seconds it took) with a bounded queue that drops the oldest waiting frame when full.

    Args:
        timestamps: (N,) seconds, the recorded frame times.
        rate_scale: playback speed (1 = recorded rate), or None: as fast as possible (frame
            ``i + 1`` arrives when frame ``i``'s result is out).
        queue_size: frames that may wait while one is processed (>= 1).
        wall_clock: at the recorded rate, wait for each arrival for real and read the clock
            (``perf_counter``) instead of advancing a virtual one by the processing times: a
            worker process (the landmark window's, ``--vio-backends process``) computes while
            the consumer waits, which a virtual clock that skips idle time would not allow.
    """
    if queue_size < 1:
        raise ValueError(f"queue_size must be >= 1, got {queue_size}")
    n = len(timestamps)
    if rate_scale is None:
        out = Replay(np.zeros(n), afap=True)
        clock = 0.0
        for i in range(n):
            out.arrivals[i] = clock
            out.processed.append(i)
            out.starts.append(clock)
            clock += process(i)
            out.finishes.append(clock)
        return out
    if not rate_scale > 0:
        raise ValueError(f"rate_scale must be positive, got {rate_scale}")
    out = Replay((np.asarray(timestamps, float) - timestamps[0]) / rate_scale)
    queue: deque[int] = deque()
    clock, nxt = 0.0, 0
    origin = time.perf_counter()
    while nxt < n or queue:
        while nxt < n and out.arrivals[nxt] <= clock:
            queue.append(nxt)
            nxt += 1
            if len(queue) > queue_size:
                out.dropped.append(queue.popleft())
        if not queue:
            if wall_clock:
                time.sleep(max(float(out.arrivals[nxt]) - (time.perf_counter() - origin), 0.0))
            clock = float(out.arrivals[nxt])
            continue
        i = queue.popleft()
        out.processed.append(i)
        out.starts.append(clock)
        seconds = process(i)
        clock = max(time.perf_counter() - origin, clock) if wall_clock else clock + seconds
        out.finishes.append(clock)
    return out


# ----------------------------------------------------------------------------- pipeline and baselines
class StreamRunner:
    """Pushes frames of ``ds`` into a fresh :class:`FrameStream`, each with the IMU samples since
    the previous push; times each push; keeps each result's timings and whether it had depth."""

    def __init__(self, ds: data.StreamData, prefetch: int = 0, matcher: str = "sift",
                 edge_guard: float | None = None, points: str | None = None,
                 backend: WindowBackendSettings | None = None, window: dict | None = None,
                 poses: str | None = None):
        self.ds = ds
        # (the vio datasets' rows without a named preset build on the reference, vio_offline: inline, sift)
        base = poses or ("vio_offline" if ds.poses == "vio" else ds.poses)
        settings = PipelineSettings.from_presets(poses=base, pairing=ds.pairing, matcher=matcher, points=points)
        if window and ds.poses == "vio":  # --vio-set: fields of the odometry or of its landmark window
            settings = with_changes(settings, window)
        if edge_guard is not None:  # --edge-guard: corners on depth edges are not fitted
            settings = replace(settings, rescaler=replace(settings.rescaler, max_disparity_spread=edge_guard))
        if backend is not None:  # where the odometry's window updates run (VioSettings.backend)
            settings = replace(settings, poses=replace(settings.poses, backend=backend))
        self.settings = settings
        self.stream = FrameStream(ds.camera, settings, imu_calibration=ds.imu, pose_kind=ds.pose_kind,
                                  prefetch=prefetch)
        self.imu_done = -np.inf
        self.seconds: list[float] = []
        self.timings: list[dict[str, float]] = []
        self.with_depth = 0
        self.statuses: dict[str, int] = {}
        self.posed: list[bool] = []  # per processed frame: the pose source gave it a pose
        self.estimates: dict[int, np.ndarray] = {}  # frame index -> the odometry's live T_w_c (vio)
        self.abs_rel: list[float] = []  # per frame with depth, where the dataset knows the true depth
        # (:meth:`preload`) the decoded frames, and the depth maps scored after the replay
        self._loaded: list | None = None
        self._deferred: list[tuple[int, np.ndarray]] = []

    def preload(self) -> None:
        """Decode every frame now and score the depth after the replay (:meth:`score_deferred`):
        with the window's worker process beside the pushes, decoding (8 ms a 752x564 frame) and
        scoring (32 ms) in the replay's wall time would take time from the pipeline and give the
        worker time it would not have on a robot."""
        self._loaded = [self.ds.load(i) for i in range(len(self.ds))]

    def held_mib(self) -> float:
        """MiB of the preloaded frames and of the depth maps kept for scoring (not the pipeline's)."""
        arrays = [a for pair in (self._loaded or []) for a in pair] + [d for _, d in self._deferred]
        return sum(a.nbytes for a in arrays) / 2**20

    def score_deferred(self) -> None:
        """Score the depth maps kept during a preloaded replay, in frame order."""
        for i, depth in sorted(self._deferred, key=lambda x: x[0]):
            self.abs_rel.append(self._abs_rel(depth, self._loaded[i][1]))
        self._deferred = []

    def inputs(self, i: int) -> tuple:
        """``(image, disparity, kwargs)`` of frame ``i``'s push (decoding: not timed)."""
        ds = self.ds
        image, disparity = ds.load(i) if self._loaded is None else self._loaded[i]
        t = float(ds.timestamps[i])
        imu = None
        if ds.imu is not None:
            new = (ds.imu.t > self.imu_done) & (ds.imu.t <= t)
            imu = (ds.imu.t[new], ds.imu.gyro[new], ds.imu.accel[new])
            self.imu_done = t
        T_w_c = None if ds.T_w_c is None else ds.T_w_c[i]
        return image, disparity, {"timestamp": t, "T_w_c": T_w_c, "imu": imu}

    def record(self, result, seconds: float) -> None:
        self.seconds.append(seconds)
        self.timings.append(dict(result.timings))
        self.with_depth += result.depth is not None
        self.statuses[result.status.value] = self.statuses.get(result.status.value, 0) + 1
        pose = result.frame_pose  # None: the poses are given (gt, imu), every frame has one
        self.posed.append(pose is None or (pose.ok and pose.T_w_c is not None))

    def __call__(self, i: int) -> float:
        image, disparity, kwargs = self.inputs(i)
        start = time.perf_counter()
        result = self.stream.push(image, disparity, **kwargs)
        seconds = time.perf_counter() - start
        self.record(result, seconds)
        self.score(i, result, disparity)  # after the timing (the replay's clock is virtual)
        return seconds

    def score(self, i: int, result, disparity: np.ndarray) -> None:
        """Keep frame ``i``'s live pose (a tracking source) and its depth's AbsRel (capped at
        :data:`ACCURACY_MAX_DEPTH_M`) where the dataset knows the truth."""
        pose = result.frame_pose
        if pose is not None and pose.ok and pose.T_w_c is not None:
            self.estimates[i] = np.asarray(pose.T_w_c, dtype=np.float64)
        if result.depth is not None and self.ds.true_depth is not None:
            if self._loaded is not None:  # preloaded: scored after the replay
                self._deferred.append((i, result.depth))
            else:
                self.abs_rel.append(self._abs_rel(result.depth, disparity))

    def _abs_rel(self, depth: np.ndarray, disparity: np.ndarray) -> float:
        """AbsRel of ``depth`` against the true depth behind ``disparity``, capped at :data:`ACCURACY_MAX_DEPTH_M`."""
        return compute_metrics(depth, self.ds.true_depth(disparity), 1e-3, ACCURACY_MAX_DEPTH_M).abs_rel

    def ate_m(self) -> float | None:
        """RMSE of the live positions against the dataset's true ones after an SE(3) alignment
        (metres), or None without truth or with fewer than 3 posed frames."""
        truth = self.ds.truth_T_w_c
        if truth is None or len(self.estimates) < 3:
            return None
        ids = sorted(self.estimates)
        t = self.ds.timestamps[ids]
        est = CameraTrajectory(t, np.stack([self.estimates[i] for i in ids]))
        return float(absolute_trajectory_error(est, CameraTrajectory(t, truth[ids])).translation.rmse)

    def overlapped(self, window: int) -> Replay:
        """Every frame through ``submit``, at most ``window`` in flight (mode ``prefetch``)."""
        n = len(self.ds)
        out = Replay(np.zeros(n), afap=True)
        inputs = [self.inputs(i) for i in range(n)]  # decoded beforehand: not timed
        done = np.zeros(n)
        futures: deque = deque()
        origin = time.perf_counter()
        with self.stream:
            for i in range(n + window):
                if len(futures) == window or (i >= n and futures):
                    k, fut = futures.popleft()
                    result = fut.result()
                    self.record(result, done[k] - out.arrivals[k])
                    out.processed.append(k)
                    out.starts.append(out.arrivals[k])
                    out.finishes.append(done[k])
                if i < n:
                    image, disparity, kwargs = inputs[i]
                    out.arrivals[i] = time.perf_counter() - origin
                    fut = self.stream.submit(image, disparity, **kwargs)
                    fut.add_done_callback(lambda _f, k=i: done.__setitem__(k, time.perf_counter() - origin))
                    futures.append((i, fut))
        return out


class BareSift:
    """OpenCV SIFT with the project's settings, detect + describe per frame."""

    name = "bare SIFT"

    def __init__(self):
        s = SiftSettings()
        self.sift = cv2.SIFT_create(nfeatures=s.max_features, nOctaveLayers=s.n_octave_layers,
                                    contrastThreshold=s.contrast_threshold, edgeThreshold=s.edge_threshold,
                                    sigma=s.sigma)

    def __call__(self, image: np.ndarray) -> None:
        self.sift.detectAndCompute(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), None)


class BareKlt:
    """KLT tracks frame to frame, topped up with corners away from the tracks when too few survive."""

    name = "bare KLT"

    def __init__(self):
        self.prev: np.ndarray | None = None
        self.points = np.zeros((0, 1, 2), np.float32)
        self.tracked: list[int] = []

    def __call__(self, image: np.ndarray) -> None:
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        if self.prev is not None and len(self.points):
            nxt, ok, _ = cv2.calcOpticalFlowPyrLK(self.prev, grey, self.points, None, winSize=(21, 21), maxLevel=3)
            self.points = nxt[ok.ravel() == 1].reshape(-1, 1, 2)
        self.tracked.append(len(self.points))
        if len(self.points) < KLT_MIN:
            mask = np.full(grey.shape, 255, np.uint8)
            for x, y in self.points.reshape(-1, 2):
                cv2.circle(mask, (int(x), int(y)), KLT_SPACING, 0, -1)
            new = cv2.goodFeaturesToTrack(grey, KLT_MAX - len(self.points), 0.01, KLT_SPACING, mask=mask)
            if new is not None:
                self.points = np.concatenate([self.points, new.astype(np.float32)])
        self.prev = grey


def run_baseline(ds: data.StreamData, baseline) -> Replay:
    def process(i: int) -> float:
        image, _ = ds.load(i)
        start = time.perf_counter()
        baseline(image)
        return time.perf_counter() - start

    return replay(ds.timestamps, process, rate_scale=None)


# ----------------------------------------------------------------------------- memory, rows, table
def reset_peak_rss() -> bool:
    """Reset this process's ``VmHWM`` to its current RSS (Linux); False when not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_mib() -> float | None:
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration):
        return None


@dataclass
class Row:
    dataset: str
    size: str
    what: str  # "vio" / "gt" / a baseline's name
    mode: str  # "realtime x1" / "afap"
    frames: int
    replay: Replay
    with_depth: int | None = None
    stages: dict[str, float] | None = None  # mean ms per stage, "other", "total"
    rss_mib: float | None = None
    statuses: dict[str, int] | None = None
    matcher: str = "-"  # the pipeline's --matcher ("-" for a baseline)
    posed: list[bool] | None = None  # per processed frame: it had a pose
    ate_m: float | None = None  # live poses against the truth (vio datasets with truth)
    abs_rel: float | None = None  # mean over the frames with depth (datasets with the true depth)
    default: bool = False  # the reference row: vio_offline (sift, two-view points, inline window)

    def steady_p99_ms(self) -> float:
        """p99 latency over the frames after the first posed one (the pose source's start-up
        -- e.g. the odometry's initialisation, a one-off -- excluded), ms; nan without any."""
        if not self.posed or not any(self.posed):
            return float("nan")
        first = self.posed.index(True)
        lat = 1000 * self.replay.latencies[first + 1:]
        return float(np.percentile(lat, 99)) if len(lat) else float("nan")

    def steady_dropped(self) -> int | None:
        """Frames dropped that arrived after the first posed frame's result was out (the start-up's
        drops -- the odometry's initialisation and its first window, taken over from the worker
        once -- excluded, as :meth:`steady_p99_ms` excludes its latency); None without a posed frame."""
        if not self.posed or not any(self.posed):
            return None
        end = self.replay.finishes[self.posed.index(True)]
        return sum(1 for i in self.replay.dropped if self.replay.arrivals[i] > end)

    def cells(self) -> list[str]:
        r = self.replay
        lat = 1000 * r.latencies
        p50, p90, p99 = (np.percentile(lat, q) for q in (50, 90, 99)) if len(lat) else (np.nan,) * 3
        baseline = self.with_depth is None
        return [self.dataset, self.size, self.what, self.matcher, self.mode, str(self.frames), str(len(r.processed)),
                "-" if baseline else str(len(r.dropped)),
                "-" if baseline or r.afap or self.steady_dropped() is None else str(self.steady_dropped()),
                "-" if baseline or r.afap else str(r.late),
                "-" if baseline else str(self.with_depth), f"{r.fps:.1f}", f"{p50:.0f}", f"{p90:.0f}", f"{p99:.0f}",
                "-" if baseline else f"{self.steady_p99_ms():.0f}",
                "-" if self.rss_mib is None else f"{self.rss_mib:.0f}",
                "-" if self.ate_m is None else f"{1000 * self.ate_m:.1f}",
                "-" if self.abs_rel is None else f"{self.abs_rel:.4f}"]


HEADER = ["dataset", "size", "poses / baseline", "matcher", "mode", "frames", "processed", "dropped",
          "dropped after start", "late",
          "with depth",
          "frames/s", "latency p50 ms", "p90 ms", "p99 ms", "p99 after start ms", "peak RSS MiB", "ATE mm",
          "AbsRel"]


def stage_means(runner: StreamRunner) -> dict[str, float]:
    n = max(len(runner.timings), 1)
    means = {s: 1000 * sum(t.get(s, 0.0) for t in runner.timings) / n for s in STAGES}
    means["total"] = 1000 * sum(runner.seconds) / n
    means["other"] = means["total"] - sum(means[s] for s in PIPELINE_STAGES)
    return means


def pipeline_row(ds: data.StreamData, rate_scale: float | None, queue_size: int, warmup: int,
                 prefetch: bool = False, matcher: str = "sift", edge_guard: float | None = None,
                 points: str | None = None, backend: WindowBackendSettings | None = None,
                 window: dict | None = None, poses: str | None = None) -> Row:
    """One row: ``ds`` replayed through a fresh stream (``poses``: a ``--poses`` preset of the vio
    datasets instead of ``ds.poses``, as the CLI builds it; the other arguments as
    :class:`StreamRunner`'s)."""
    window = window if ds.poses == "vio" else None
    if warmup:
        warm = StreamRunner(ds, 0, matcher, edge_guard, points, backend, window, poses)
        for i in range(min(warmup, len(ds))):
            warm(i)
        warm.stream.close()  # its worker process, if any, stops now, not within the timed row
        del warm
    runner = StreamRunner(ds, PREFETCH_THREADS if prefetch else 0, matcher, edge_guard, points, backend, window,
                          poses)
    # (the odometry, and its worker process, start with the first frame: the worker's start-up,
    # beside the initialisation's frames, is inside the timed row)
    vio = runner.settings.poses if isinstance(runner.settings.poses, VioSettings) else None
    backend = None if vio is None else vio.backend
    process_backend = backend is not None and backend.kind == "process"
    if process_backend and not prefetch:  # the worker runs beside the pushes: nothing else in their wall time
        runner.preload()
    # the earlier rows' pipelines are object cycles: collected now, not by a 40-90 ms pause of the
    # garbage collector within this row's frames (it happened in every row after an earlier one)
    gc.collect()
    reset_peak_rss()
    if prefetch:
        with opencv_threads(1), blas_threads(1), TorchThreads(1):
            result = runner.overlapped(PREFETCH_WINDOW)
        mode = "prefetch"
    else:
        result = replay(ds.timestamps, runner, rate_scale=rate_scale, queue_size=queue_size,
                        wall_clock=process_backend)
        mode = "afap" if rate_scale is None else f"realtime x{rate_scale:g}"
    label = ("" if poses is None else f"--poses {poses}, ") + matcher + (
        "" if edge_guard is None else f", guard {edge_guard:g}") + ("" if points is None else f", points {points}")
    if process_backend:
        label += f", worker lag {backend.lag_frames}" + (" when ready" if backend.apply_when_ready else "") + (
            f", queue {backend.max_pending_keyframes}" if backend.max_pending_keyframes > 1 else "") + (
            f", catch-up {backend.catch_up_keyframes}") + (", provisional" if backend.provisional_landmarks else "")
    label += "".join(f", {k}={v}" for k, v in (window or {}).items())
    default = (matcher == "sift" and points is None and not process_backend and not window
               and poses in (None, "vio_offline"))
    rss = peak_rss_mib()
    rss = None if rss is None else rss - runner.held_mib()  # (preloaded rows: the frames and kept depth maps out)
    runner.stream.close()
    runner.score_deferred()
    return Row(ds.name, ds.size, ds.poses, mode, len(ds), result, runner.with_depth, stage_means(runner),
               rss, dict(runner.statuses), label, list(runner.posed), runner.ate_m(),
               float(np.mean(runner.abs_rel)) if runner.abs_rel else None, default)


def baseline_row(ds: data.StreamData, baseline) -> Row:
    reset_peak_rss()
    result = run_baseline(ds, baseline)
    return Row(ds.name, ds.size, baseline.name, "afap", len(ds), result, rss_mib=peak_rss_mib())


def preset_specs(presets: list[str], points: list[str], modes: list[str]) -> list[tuple[str, str, str, str]]:
    """``(matcher, points, mode, preset)`` of each ``--pose-presets`` row: the matcher and, unless
    ``points`` names some (``--vio-points``), the points the CLI takes with that preset."""
    return [(default_matcher_preset(POSE_PRESETS[p]), source, mode, p)
            for p in presets for source in (points or [default_points_spec(POSE_PRESETS[p])]) for mode in modes]


def with_changes(settings: PipelineSettings, changes: dict) -> PipelineSettings:
    """``settings`` with each ``FIELD: value`` set on the odometry's window (``LandmarkSettings``), or
    else on the odometry (``VioSettings``; ``backend`` as a tuple of ``WindowBackendSettings``' fields);
    ValueError for a field of neither (``--vio-set`` here, ``bench_vio_online.py --set``)."""
    vio = settings.poses
    window_fields = {f.name for f in dataclasses.fields(vio.window)}
    vio_fields = {f.name for f in dataclasses.fields(vio)}
    unknown = [k for k in changes if k not in window_fields | vio_fields]
    if unknown:
        raise ValueError(f"unknown field(s) {', '.join(unknown)} (valid: LandmarkSettings or VioSettings fields)")
    if "backend" in changes:  # e.g. --set "backend=('process', 6)": WindowBackendSettings' fields
        b = changes["backend"]
        changes = {**changes, "backend": WindowBackendSettings(*(b if isinstance(b, tuple) else (b,)))}
    window = replace(vio.window, **{k: v for k, v in changes.items() if k in window_fields})
    vio = replace(vio, window=window, **{k: v for k, v in changes.items() if k not in window_fields})
    return replace(settings, poses=vio)


def parse_vio_changes(text: str) -> dict:
    """``"FIELD=VALUE;FIELD=VALUE"`` as ``{field: value}`` (values as Python literals; ``""``: none);
    ValueError for an item that is not one. The fields are checked by :func:`with_changes`."""
    changes = {}
    for item in (t for t in text.split(";") if t.strip()):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"{item!r} is not FIELD=VALUE")
        try:
            changes[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            raise ValueError(f"{item!r}: the value is not a Python literal") from None
    return changes


def parse_window(text: str) -> dict:
    """``--vio-set``'s ``"key=value;key=value"`` (:func:`parse_vio_changes`), fields of
    :class:`VioSettings` or :class:`LandmarkSettings` other than ``window`` and ``backend``
    (``--vio-backends``, ``--vio-lag`` set those); ``""``: no change."""
    try:
        changes = parse_vio_changes(text)
        if {"window", "backend"} & set(changes):
            raise ValueError("window and backend are not set here (--vio-backends, --vio-lag)")
        with_changes(PipelineSettings.from_presets(poses="vio"), changes)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"--vio-set {text!r}: {exc}") from None
    return changes


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def accuracy_against_default(row: Row, rows: list[Row]) -> tuple[str, bool]:
    """The verdict's accuracy clause for a vio row, and whether it holds: its ATE and AbsRel
    against the reference configuration's (vio_offline) afap row of the same dataset in this run (issue 24:
    within 10 % and 5 %); it holds where nothing can be compared (the text says why)."""
    if row.ate_m is None and row.abs_rel is None:
        return "; accuracy: no truth in this dataset", True
    base = [r for r in rows if r.dataset == row.dataset and r.what == "vio" and r.default and r.mode == "afap"]
    ate = "-" if row.ate_m is None else f"{1000 * row.ate_m:.1f} mm"
    text = f"; ATE {ate}, AbsRel {'-' if row.abs_rel is None else f'{row.abs_rel:.4f}'}"
    if row.default:
        return text + " (the reference configuration, vio_offline)", True
    if not base:
        return text + " (no reference row in this run to compare with)", True
    b = base[0]
    checks, held = [], True
    if row.ate_m is not None and b.ate_m:
        ratio = row.ate_m / b.ate_m
        held &= ratio <= 1 + ATE_TOLERANCE
        checks.append(f"ATE {ratio:.2f} x the reference's {1000 * b.ate_m:.1f} mm "
                      f"({'within' if ratio <= 1 + ATE_TOLERANCE else 'beyond'} +{ATE_TOLERANCE:.0%})")
    if row.abs_rel is not None and b.abs_rel:
        ratio = row.abs_rel / b.abs_rel
        held &= ratio <= 1 + ABS_REL_TOLERANCE
        checks.append(f"AbsRel {ratio:.2f} x the reference's {b.abs_rel:.4f} "
                      f"({'within' if ratio <= 1 + ABS_REL_TOLERANCE else 'beyond'} +{ABS_REL_TOLERANCE:.0%})")
    return text + ("; " + ", ".join(checks) if checks else ""), held


def verdicts(rows: list[Row]) -> list[str]:
    """Issue 24's targets on the rows measured."""
    out = []
    for row in rows:
        if row.what == "vio" and row.mode == "afap":
            rt = [r for r in rows if r.dataset == row.dataset and r.what == "vio" and r.matcher == row.matcher
                  and r.mode == "realtime x1"]
            ok_fps = row.replay.fps >= 20
            size = row.size if row.size == "752x480" else f"{row.size}, indicative: the target is stated for 752x480"
            what = row.matcher if row.matcher.startswith("--poses") else f"--poses vio --matcher {row.matcher}"
            text = f"- {row.dataset} {what} ({size}): {row.replay.fps:.1f} frames/s " \
                   f"as fast as possible ({'>=' if ok_fps else '<'} 20)"
            ok = ok_fps
            if rt:
                p99 = float(np.percentile(1000 * rt[0].replay.latencies, 99))
                steady = rt[0].steady_p99_ms()
                drops = len(rt[0].replay.dropped)
                # sustained: none dropped once the first frame is posed (the start-up -- the odometry's
                # initialisation and its first window, taken over from the worker -- is a one-off
                # that delays the first pose, which p99 over all frames still counts)
                steady_drops = rt[0].steady_dropped()
                ok = ok and p99 <= 100 and steady_drops == 0
                text += f"; at the recorded rate: p99 {p99:.0f} ms ({'<=' if p99 <= 100 else '>'} 100; " \
                        f"{steady:.0f} ms after the start), {drops} of {rt[0].frames} frames dropped " \
                        f"({'no posed frame' if steady_drops is None else steady_drops} after the start)"
            else:
                text += "; no recorded-rate row (p99 target not checked)"
            accuracy, held = accuracy_against_default(row, rows)
            text += accuracy
            ok = ok and held
            if not row.with_depth:  # e.g. the EuRoC slice, whose camera is still: nothing was tracked in motion
                out.append(f"{text}; no frame got depth (a still camera, or never tracked): **NOT JUDGED**")
                continue
            out.append(f"{text}: **{'PASS' if ok else 'FAIL'}**")
        if row.what == "gt" and row.size == "1242x375" and row.mode in ("afap", "prefetch"):
            sift = [r for r in rows if r.dataset == row.dataset and r.what == BareSift.name]
            if not sift:
                out.append(f"- {row.dataset} --poses gt (1242x375): no bare SIFT row (baselines off): not checked")
                continue
            ratio = row.replay.fps / sift[0].replay.fps
            out.append(f"- {row.dataset} --poses gt --matcher {row.matcher} (1242x375, {row.mode}): "
                       f"{row.replay.fps:.1f} frames/s = {ratio:.2f} x "
                       f"bare SIFT "
                       f"({sift[0].replay.fps:.1f}) ({'>=' if ratio >= 0.8 else '<'} 0.8): "
                       f"**{'PASS' if ratio >= 0.8 else 'FAIL'}**")
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default=",".join(data.DATASETS),
                        help=f"comma-separated, of {', '.join(data.DATASETS)}")
    parser.add_argument("--max-frames", type=int, default=None, help="first N frames of each dataset")
    parser.add_argument("--rate-scale", type=float, default=1.0, help="playback speed of the recorded rate")
    parser.add_argument("--modes", default="realtime,afap,prefetch",
                        help="realtime (at --rate-scale), afap and/or prefetch")
    parser.add_argument("--queue-size", type=int, default=1, help="frames that may wait (oldest dropped when full)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed frames streamed before each pipeline row")
    parser.add_argument("--matchers", default="sift,klt",
                        help="the pipeline's --matcher presets, one row set each (on vio_offline's settings: sift, its "
                             "matcher; klt: the KLT tracking front end)")
    parser.add_argument("--klt-edge-guard", type=float, default=0.1,
                        help="the klt rows' --edge-guard (points on depth edges not fitted; the corners sit on them)")
    parser.add_argument("--vio-points", default=None,
                        help="comma-separated --points sources of the vio datasets' rows, one row set each (sfm: "
                             "two-view pairs matched and triangulated again; vio: the odometry's own landmarks, no "
                             "second matching); default: sfm, and with --pose-presets each preset's own default "
                             "(vio with vio, sfm with vio_offline), as the CLI")
    parser.add_argument("--vio-backends", default="inline",
                        help="comma-separated, where the vio rows' window updates run, one row set each: inline "
                             "(vio_offline's: a keyframe's frame waits for its update) and/or process (a worker "
                             "process beside the tracking; recorded-rate rows then run on the wall clock)")
    parser.add_argument("--vio-lag", type=int, default=WindowBackendSettings().lag_frames,
                        help="process backend: frames after a keyframe at which its update is taken over")
    parser.add_argument("--vio-max-pending", type=int, default=WindowBackendSettings().max_pending_keyframes,
                        help="process backend: keyframes queued in the worker at most (1: none chosen while one "
                             "is pending)")
    parser.add_argument("--vio-catch-up", type=int, default=WindowBackendSettings().catch_up_keyframes,
                        help="process backend: candidates collected while the start's attempt ran that join its "
                             "window")
    parser.add_argument("--vio-provisional", action="store_true",
                        help="process backend: the frames of the lag matched and queried against the window "
                             "extended by the pending keyframe (provisional landmarks)")
    parser.add_argument("--vio-when-ready", action="store_true",
                        help="process backend: take an update over as soon as it is ready (timing-dependent)")
    parser.add_argument("--vio-set", action="append", default=None, metavar="KEY=VALUE;...",
                        help="one row set per use: fields of the odometry (VioSettings) or of its landmark window "
                             "(LandmarkSettings) replaced, e.g. \"solver='isam2';bridge_every_update=False\"; "
                             "'' = the preset's")
    parser.add_argument("--pose-presets", default="",
                        help="comma-separated --poses presets of the vio datasets' rows (e.g. vio_offline,vio), "
                             "each as the CLI builds it with its default matcher; replaces --matchers, "
                             "--vio-backends, --vio-lag and --vio-set for those rows")
    parser.add_argument("--no-baselines", action="store_true")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    args = parser.parse_args(argv)
    try:
        windows = [parse_window(w) for w in (args.vio_set or [""])]
    except ValueError as exc:
        parser.error(str(exc))
    names = [n for n in args.datasets.split(",") if n]
    unknown = [n for n in names if n not in data.DATASETS]
    modes = [m for m in args.modes.split(",") if m]
    matchers = [m for m in args.matchers.split(",") if m]
    bad = [m for m in matchers if m not in MATCHER_PRESETS]
    if bad or not matchers:
        parser.error(f"unknown matcher(s) {', '.join(bad) or '(none)'} (valid: {', '.join(MATCHER_PRESETS)})")
    presets = [p for p in args.pose_presets.split(",") if p]
    vio_names = [n for n in POSE_PRESETS if isinstance(POSE_PRESETS[n], VioSettings)]
    bad_presets = [p for p in presets if p not in vio_names]
    if bad_presets:
        parser.error(f"unknown --pose-presets {', '.join(bad_presets)} (valid: {', '.join(vio_names)})")
    vio_points = [p for p in (args.vio_points or ("" if presets else "sfm")).split(",") if p]
    if (args.vio_points is not None or not presets) and (not vio_points or not set(vio_points) <= {"sfm", "vio"}):
        parser.error(f"unknown --vio-points {args.vio_points!r} (valid: sfm, vio)")
    try:
        backends = [WindowBackendSettings(b, args.vio_lag, args.vio_when_ready,
                                          catch_up_keyframes=args.vio_catch_up,
                                          max_pending_keyframes=args.vio_max_pending,
                                          provisional_landmarks=args.vio_provisional and b != "inline")
                    for b in args.vio_backends.split(",") if b]
    except ValueError as exc:
        parser.error(str(exc))
    if not backends:
        parser.error("--vio-backends: none given (valid: inline, process)")
    if unknown:
        parser.error(f"unknown dataset(s) {', '.join(unknown)} (valid: {', '.join(data.DATASETS)})")
    if not modes or not set(modes) <= {"realtime", "afap", "prefetch"}:
        parser.error(f"unknown mode(s) in {args.modes!r} (valid: realtime, afap, prefetch)")
    if not args.rate_scale > 0 or args.queue_size < 1:
        parser.error("--rate-scale must be positive and --queue-size at least 1")
    print(f"# machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads), numpy "
          f"{np.__version__}; load average {os.getloadavg()[0]:.1f} at start. Times on a shared machine vary.")
    print(f"# replay: rate x{args.rate_scale:g}, queue {args.queue_size} (oldest dropped), "
          f"warm-up {args.warmup} frames")
    rows: list[Row] = []
    for name in names:
        ds = data.DATASETS[name](args.cache, log=print)
        if ds is None:
            print(f"\n({name}: data not present under {data.SHARED}: skipped)")
            continue
        ds = ds.truncated(args.max_frames)
        rate = (len(ds) - 1) / (ds.timestamps[-1] - ds.timestamps[0]) if len(ds) > 1 else float("nan")
        print(f"\n## {name} ({ds.size}, {len(ds)} frames, {rate:.1f} Hz, --poses {ds.poses}, --pairing "
              f"{ds.pairing}): {ds.description}", flush=True)
        sources = vio_points if ds.poses == "vio" else [None]
        where = backends if ds.poses == "vio" else [None]
        if ds.poses == "vio" and presets:  # the CLI's named configurations, each with its own matcher and points
            specs = [(matcher, points, None, {}, mode, p)
                     for matcher, points, mode, p in preset_specs(presets, vio_points, modes)]
        else:
            specs = [(*spec, None) for spec in itertools.product(matchers, sources, where, windows, modes)]
        for matcher, points, backend, window, mode, preset in specs:
            if mode == "prefetch" and matcher == "klt":
                continue  # a tracker follows the previous frame: nothing to extract ahead
            row = pipeline_row(ds, args.rate_scale if mode == "realtime" else None, args.queue_size, args.warmup,
                               prefetch=mode == "prefetch", matcher=matcher,
                               edge_guard=args.klt_edge_guard if matcher == "klt" else None,
                               points=None if points == "sfm" else points,
                               backend=None if backend is None or backend.kind == "inline" else backend,
                               window=window, poses=preset)
            rows.append(row)
            print(f"  {row.matcher} {row.mode}: {row.replay.fps:.1f} frames/s, statuses {row.statuses}", flush=True)
        if not args.no_baselines:
            for baseline in (BareSift(), BareKlt()):
                rows.append(baseline_row(ds, baseline))
                print(f"  {baseline.name}: {rows[-1].replay.fps:.1f} frames/s", flush=True)
    if not rows:
        print("no dataset present: nothing measured")
        return 0
    print("\n" + table(HEADER, [r.cells() for r in rows]))
    stage_rows = [[r.dataset, r.what, r.matcher, r.mode, *(f"{r.stages[s]:.1f}" for s in (*STAGES, "other", "total"))]
                  for r in rows if r.stages is not None]
    print("\nPer stage, mean ms per processed frame (matching and triangulation are parts of points):\n")
    print(table(["dataset", "poses", "matcher", "mode", *STAGES, "other", "total"], stage_rows))
    print("\nVerdict against issue 24's targets:")
    print("\n".join(verdicts(rows)) or "- no row of a target's kind measured")
    return 0


if __name__ == "__main__":
    sys.exit(main())
