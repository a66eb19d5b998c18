"""Pushing frames from arrays: the pipeline for a ROS node, a notebook or any live source.

:class:`FrameStream` takes, per frame, the image, its disparity, the timestamp and a pose
(``T_w_c``) and/or the IMU samples since the previous frame, and returns the frame's
:class:`~vio_depth.pipeline.FrameResult`. No sequence folder and no adapter classes::

    stream = FrameStream(camera, PipelineSettings.from_presets(pairing="indoor"))
    for t, image, disparity, T_w_c in source:
        result = stream.push(image, disparity, timestamp=t, T_w_c=T_w_c)
        if result.depth is not None:
            ...  # (H, W) float32 metres, NaN = invalid

When frames may arrive faster than they are processed, :meth:`FrameStream.submit` queues a
frame and returns a future of its result: frames are processed in submission order in one
background thread, and with ``prefetch`` threads the features of the frames waiting are
extracted ahead, while earlier frames are matched and fitted (feature extraction needs
nothing of the stream's state). That is how the CLI run overlaps (:mod:`vio_depth.run.overlap`),
and on a few cores the only way past one detector's throughput; the results are those
:meth:`FrameStream.push` gives, bit for bit.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import CorruptImageError, InputError

from ..disparity import DisparityKind, check_disparity
from ..frame import Frame, ImuData
from .build import build_matcher, build_pose_stage
from .feed import LazyImuPoses, StreamInputs
from .pipeline import Pipeline
from .result import FrameResult
from .settings import PipelineSettings


class _GivenDisparity:
    """The disparity handed over with the frame being pushed."""

    kind = DisparityKind.ARRAY

    def __init__(self):
        self.current: np.ndarray | None = None

    def __call__(self, frame: Frame) -> np.ndarray | None:
        if self.current is None:
            return None
        return check_disparity(self.current, frame, f"disparity of frame {frame.index}")


class FrameStream:
    """The streaming pipeline fed with arrays, one frame at a time.

    Args:
        camera: intrinsics of the images.
        settings: pipeline settings; ``settings.poses`` decides what each push needs: the
            ``gt`` source takes ``T_w_c`` (camera-to-world, metres), the ``imu`` source the
            IMU samples (and ``imu_calibration``), plus ``T_w_c`` when known; the ``vio``
            source the IMU samples and ``imu_calibration`` only (a ``T_w_c`` is ignored).
        imu_calibration: for the ``imu`` and ``vio`` pose sources: an
            :class:`~vio_depth.frame.ImuData` whose ``T_c_i``, noise densities and gravity
            are used (its samples are ignored).
        pose_kind: what the pushed ``T_w_c`` are (a
            :data:`~vio_depth.poses.POSE_UNCERTAINTY_PRESETS` name: ``mocap``, ``ins``,
            ``headset``, ``kinectfusion``; ``exact`` for rendered poses), for the ``gt``
            source's stated uncertainty when ``settings.poses.uncertainty`` names none.
        prefetch: threads that extract the features of :meth:`submit`-ted frames ahead of
            their processing (0: none, every stage in the processing thread). Only a matcher
            whose ``extract`` is safe in any thread and needs no earlier frame
            (``concurrent_extract``: SIFT) extracts ahead; with others ``prefetch`` is 0. The process-wide
            thread pools (OpenCV, BLAS, torch) are left as they are:
            on 2 cores, ``cv2.setNumThreads(1)`` with ``prefetch=2`` is what the CLI run does.

    A stream holds threads once a frame was submitted, and with a ``process`` backend
    (``--poses vio``) a worker process from the start: :meth:`close` it (or use it as a
    context manager) when done.
    """

    def __init__(self, camera: Camera, settings: PipelineSettings | None = None, *,
                 imu_calibration: ImuData | None = None, pose_kind: str = "exact", prefetch: int = 0):
        settings = PipelineSettings() if settings is None else settings
        if not isinstance(camera, Camera):
            raise InputError(f"camera must be a vio_core.Camera, got {type(camera).__name__}")
        self.camera = camera
        self._disparity = _GivenDisparity()
        self._inputs = StreamInputs(pose_kind, imu_calibration)
        matcher = build_matcher(settings)
        poses = self._poses = build_pose_stage(settings.poses, matcher=matcher, stream=self._inputs)
        self.pipeline = Pipeline(settings, poses, self._disparity, matcher=matcher, imu_of=lambda: self._inputs.imu)
        self._pose_source = poses.source
        if isinstance(prefetch, bool) or not isinstance(prefetch, int) or prefetch < 0:
            raise InputError(f"prefetch must be an integer >= 0, got {prefetch!r}")
        concurrent = getattr(matcher, "concurrent_extract", False) is True  # as the CLI run decides
        self.prefetch = 0 if matcher is None or not concurrent else prefetch
        self._submitted = 0  # frames accepted so far (push or submit)
        self._last_t = -np.inf
        self._extract: ThreadPoolExecutor | None = None
        self._ordered: ThreadPoolExecutor | None = None
        self._closed = False

    @property
    def settings(self) -> PipelineSettings:
        return self.pipeline.settings

    @property
    def workers(self) -> tuple:
        """The worker processes (:class:`~vio_depth.landmarks.ProcessWindow`) the stream started
        (``--poses vio``'s window; a ``process`` points window); :meth:`close` stops them."""
        return self._poses.workers + self.pipeline.workers

    def push(self, image, disparity, *, timestamp: float | None = None, T_w_c=None, imu=None,
             gt_depth=None) -> FrameResult:
        """Process the next frame.

        Args:
            image: (H, W, 3) uint8 RGB (or (H, W) grey) of the camera's size.
            disparity: (H, W) float affine-invariant disparity (bigger = nearer), NaN = invalid,
                or None (the frame then gets status no_disparity).
            timestamp: seconds, increasing (default: the frame number).
            T_w_c: (4, 4) camera-to-world pose, metres, or None.
            imu: the IMU samples since the previous push: ``(t (M,) s, gyro (M, 3) rad/s,
                accel (M, 3) m/s^2)``, or None.
            gt_depth: (H, W) metres ground truth (0 = invalid), for reference point sources.

        Raises:
            ShapeError / InputError: wrongly shaped arrays, decreasing time, a missing input
                the pose source needs.
        """
        if self._ordered is not None:  # frames submitted before are processed first
            return self.submit(image, disparity, timestamp=timestamp, T_w_c=T_w_c, imu=imu,
                               gt_depth=gt_depth).result()
        return self._process(*self._accept(image, disparity, timestamp, T_w_c, imu, gt_depth), None)

    def submit(self, image, disparity, *, timestamp: float | None = None, T_w_c=None, imu=None,
               gt_depth=None) -> Future:
        """Queue the next frame (arguments as :meth:`push`); returns a ``Future`` of its
        :class:`~vio_depth.pipeline.FrameResult`.

        The inputs are checked here (the same errors as :meth:`push`, raised at once); the
        frame is processed after every frame submitted before it, in one background thread,
        its features extracted ahead by the ``prefetch`` threads. An error while processing
        is raised by the future's ``result()``. The queue is not bounded: a live source that
        produces faster than the stream processes should drop frames before submitting them.
        The arrays must not be changed until the future is done.
        """
        accepted = self._accept(image, disparity, timestamp, T_w_c, imu, gt_depth)
        if self._ordered is None:
            self._ordered = ThreadPoolExecutor(1, thread_name_prefix="vio-depth-stream")
            if self.prefetch:
                self._extract = ThreadPoolExecutor(self.prefetch, thread_name_prefix="vio-depth-stream-prefetch")
        features = None if self._extract is None else self._extract.submit(self._extract_timed, accepted[1])
        return self._ordered.submit(self._process, *accepted, features)

    def close(self) -> None:
        """Wait for the submitted frames, then stop the stream's threads and worker processes;
        the stream takes no frame after this (:class:`InputError`). Closing twice is harmless."""
        for pool in (self._ordered, self._extract):
            if pool is not None:
                pool.shutdown(wait=True)
        self._ordered = self._extract = None
        if not self._closed:
            self._closed = True
            self.pipeline.close()
            self._poses.close()

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _accept(self, image, disparity, timestamp, T_w_c, imu, gt_depth):
        """The checked inputs of the next frame (in the caller's thread), its index taken."""
        if self._closed:
            raise InputError("the stream is closed (FrameStream.close): make a new one for more frames")
        image = np.asarray(image)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        image = check_image("image", image, channels=3)
        if image.shape[:2] != (self.camera.height, self.camera.width) or image.dtype != np.uint8:
            raise InputError(f"image: expected ({self.camera.height}, {self.camera.width}, 3) uint8, "
                             f"got {image.shape} {image.dtype}")
        t = float(self._submitted if timestamp is None else timestamp)
        if not t > self._last_t:
            raise InputError(f"timestamps must increase: {t} after {self._last_t}")
        pose = None if T_w_c is None else check_transform("T_w_c", T_w_c)
        depth = None if gt_depth is None else check_array("gt_depth", gt_depth, image.shape[:2]).astype(np.float32)
        index, self._submitted, self._last_t = self._submitted, self._submitted + 1, t
        return index, image, disparity, t, pose, depth, imu

    def _extract_timed(self, image: np.ndarray):
        """``(features, seconds)`` of ``image``, or ``(None, 0)`` when its data are damaged (the
        processing thread then extracts again and reports it as :meth:`push` does)."""
        start = time.perf_counter()
        try:
            features = self.pipeline.matcher.extract(image)
        except CorruptImageError:
            return None, 0.0
        return features, time.perf_counter() - start

    def _process(self, index, image, disparity, t, pose, depth, imu, features: Future | None):
        """The frame's stages, in stream order; ``features``: its features extracted ahead."""
        if imu is not None:
            self._inputs.add_imu(*imu)
        frame = Frame(index, t, f"{index:06d}", self.camera, pose, load_image=lambda: image,
                      load_gt_depth=None if depth is None else (lambda: depth))
        self._inputs.add_frame(frame)
        self._disparity.current = None if disparity is None else np.asarray(disparity)
        try:
            extracted, seconds = (None, 0.0) if features is None else features.result()
            if extracted is None:
                result = self.pipeline.process(frame)
            else:
                prepared = self.pipeline.prepare(frame, extracted)
                prepared.timings.update(image=0.0, features=seconds)
                result = self.pipeline.process_prepared(prepared)
        finally:
            self._disparity.current = None
        self._forget(t)
        return result

    def _forget(self, t: float) -> None:
        """Drop the past frames and IMU samples that nothing reads again (a long stream's memory
        stays flat): the ``imu`` / ``vio`` source says how far back it reads; with the other
        sources only a tracking matcher's rotation reads samples, from the frame at ``t`` on."""
        source = self._pose_source
        since = source.samples_needed_since() if isinstance(source, LazyImuPoses) else t
        if since is not None:
            self._inputs.forget_before(since)
