"""The streaming pipeline: frame -> features -> points -> fit -> metric depth.

One :class:`Pipeline` processes frames in order (``process(frame)``). Every per-frame
failure is a :class:`~vio_depth.pipeline.FrameStatus` with a reason; nothing in here raises
for a bad frame (only for bad *input*, e.g. an unreadable image).
"""

from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import replace
from typing import Callable, ContextManager

from matchers import Features, FrameTracker, Matcher
from vio_core.errors import CorruptImageError

from ..disparity import DisparitySource, check_inversion, check_map_content, missing_disparity_reason
from ..frame import Frame, ImuData
from ..poses import GroundTruthPoseSettings, PoseSource, TrackingPoseSource
from ..rescale import Rescaler, disparity_spread, sample_bilinear
from .build import PoseStage, build_stages
from .point_source import PointSourceKind
from .result import FrameResult, PointsOutcome, PreparedFrame
from .settings import PipelineSettings
from .status import FrameStatus, decide_frame_status
from .tracking import TrackedExtraction

log = logging.getLogger(__name__)


class Pipeline:
    """Streaming metric-depth pipeline over the frames of one camera.

    Its stages are built by :func:`~vio_depth.pipeline.build_stages` from ``settings``,
    except those given here.

    Args:
        settings: see :class:`PipelineSettings`.
        pose_source: relative poses between frames (a tracker when it implements
            :class:`~vio_depth.poses.TrackingPoseSource`), or a
            :class:`~vio_depth.pipeline.PoseStage`; default: built from ``settings.poses``
            for ``sequence`` (the ``gt`` source needs none).
        disparity_source: each frame's affine-invariant disparity; default: built from
            ``settings.disparity`` for ``sequence``.
        sequence: the sequence the frames come from, when the default sources need it
            (IMU samples, the disparity it carries).
        matcher: a ready matcher instead of one built from ``settings.matcher``.
        imu_of: returns the IMU samples known so far, for a tracking matcher's rotation
            prediction (:mod:`vio_depth.pipeline.tracking`); default: ``sequence.imu``.
    """

    def __init__(self, settings: PipelineSettings | None = None, pose_source: PoseSource | PoseStage | None = None,
                 disparity_source: DisparitySource | None = None, *, sequence=None, matcher: Matcher | None = None,
                 imu_of: Callable[[], ImuData | None] | None = None):
        self.settings = settings = PipelineSettings() if settings is None else settings
        self.sequence = sequence
        stages = build_stages(settings, sequence, pose_source, disparity_source, matcher)
        self._matcher = stages.matcher
        #: the pose source and whether it tracks the frames
        self.poses: PoseStage = stages.poses
        self.pose_source: PoseSource = stages.poses.source
        #: the pose source that estimates poses from the frames itself (visual-inertial odometry), or None
        self.tracker: TrackingPoseSource | None = stages.poses.tracker
        self.disparity_source = stages.disparity_source
        self.rescaler = Rescaler(settings.rescaler)
        self.points = stages.points
        # the worker processes this pipeline started (:meth:`close`): a given pose stage's are its giver's
        self._workers = (stages.poses.workers if pose_source is None else ()) + stages.points_workers
        self._imu_of = imu_of
        matcher = self.matcher
        #: a tracking matcher's in-order extraction with its rotation prediction (None for other matchers)
        self.tracked: TrackedExtraction | None = None
        if isinstance(matcher, FrameTracker):
            if imu_of is None:
                imu = None if sequence is None else sequence.imu
                imu_of = lambda: imu  # noqa: E731
            self.tracked = TrackedExtraction(matcher, imu_of, isinstance(settings.poses, GroundTruthPoseSettings))

    @property
    def matcher(self) -> Matcher | None:
        """The matcher that extracts every frame's features (None when no stage needs features)."""
        return self.points.matcher if self.points is not None else self._matcher

    def fresh(self, inline_window: bool = False, offline_points: bool = False) -> "Pipeline":
        """A new pipeline with the same settings, sources and matcher, and no history.

        ``inline_window``: its points window (``--points landmarks``) runs in this process
        whatever ``landmarks_backend`` says -- for the offline backward pass over a few frames,
        where a worker would only add its start (1-3 s) and a second process beside the first
        pipeline's. ``offline_points``: the odometry's own landmarks (``--points vio``) become
        two-view points (``sfm``) with the odometry's poses -- for the backward pass, whose frames
        the odometry posed only afterwards (an initialisation's, while its scale converged) and
        so never matched against its landmarks."""
        settings = self.settings
        if inline_window and settings.landmarks_backend.kind != "inline":
            settings = replace(settings, landmarks_backend=replace(settings.landmarks_backend, kind="inline"))
        if offline_points and settings.points.kind == PointSourceKind.VIO:
            settings = replace(settings, points=replace(settings.points, kind=PointSourceKind.SFM))
        return Pipeline(settings, self.poses, self.disparity_source, sequence=self.sequence,
                        matcher=self.matcher, imu_of=self._imu_of)

    @property
    def workers(self) -> tuple:
        """The worker processes (:class:`~vio_depth.landmarks.ProcessWindow`) this pipeline started
        and :meth:`close` stops (a pose stage handed in keeps its own)."""
        return self._workers

    def finish_sequence(self) -> None:
        """The sequence ended (an offline run, before its backward pass): the pose source settles
        what it still has pending (:meth:`~vio_depth.poses.TrackingPoseSource.finish`: the
        odometry's worker may hold an initialisation, its start or a keyframe update not due
        yet); the frames it poses then can get depth from the backward pass. A live stream has
        no end to settle."""
        if self.tracker is not None:
            self.tracker.finish()

    def close(self) -> None:
        """Stop the worker processes this pipeline started (a ``process`` backend of the
        odometry's or the points window): it processes no frame after this. Without it they stop
        when the pipeline is garbage-collected (at a moment no frame chooses: a collection
        of the pipeline's object cycles takes tens of ms) or with the interpreter."""
        for worker in self._workers:
            worker.close()

    def __enter__(self) -> "Pipeline":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ per frame
    def process(self, frame: Frame) -> FrameResult:
        """Process the next frame of the stream and return its result (with ``depth``)."""
        return self.process_prepared(self.prepare(frame))

    def prepare(self, frame: Frame, features: Features | None = None,
                in_order: ContextManager | None = None) -> PreparedFrame:
        """The frame's stateless stages: image decoding, features, disparity.

        They read nothing of the pipeline's state (keyframes, filter), so frames may be
        prepared ahead of :meth:`process_prepared`, in other threads (several at once when
        the matcher's ``concurrent_extract`` is true: SIFT keeps one detector per thread).
        A tracking matcher (KLT, :attr:`tracked`) follows the previously prepared frame, so
        its frames come in order: one thread, or several that each enter ``in_order`` (their
        turn, :class:`vio_depth.run.overlap.Prefetcher` with ``ordered``) for the image and
        the tracking, while the disparity runs concurrently. ``features``: this frame's
        features extracted earlier by the same matcher (the image is then not read here).
        """
        timings: dict[str, float] = {}
        clock = time.perf_counter
        matcher = self.matcher
        try:
            if matcher is not None and features is None:
                with in_order if in_order is not None else contextlib.nullcontext():
                    t = clock()
                    image = frame.image()  # read once: a model disparity source gets the same pixels
                    frame = replace(frame, load_image=lambda: image)
                    timings["image"] = clock() - t
                    t = clock()
                    # once per frame, kept if keyframe; a tracker follows the previous frame
                    features = matcher.extract(image) if self.tracked is None else self.tracked(frame, image)
                    timings["features"] = clock() - t
            t = clock()
            disparity = self.disparity_source(frame)
            timings["disparity"] = clock() - t
        except CorruptImageError as exc:  # damaged pixels: a status, the run goes on (docs/safety.md)
            return PreparedFrame(frame, None, None, timings, corrupt_image=str(exc))
        return PreparedFrame(frame, features, disparity, timings)

    def process_prepared(self, prepared: PreparedFrame) -> FrameResult:
        """The stateful stages of a :meth:`prepare`-d frame, in stream order: tracking (a
        tracking pose source), pairing, triangulation, fit, depth. ``process(frame)`` is
        ``process_prepared(prepare(frame))``."""
        frame, features, disparity = prepared.frame, prepared.features, prepared.disparity
        timings = dict(prepared.timings)
        if prepared.corrupt_image:  # seen by no stage: pairing, tracking and the filter skip it
            return FrameResult(frame.index, frame.stem, frame.timestamp, FrameStatus.CORRUPT_IMAGE,
                               prepared.corrupt_image, self.settings.points, PointsOutcome(FrameStatus.CORRUPT_IMAGE, ""),
                               timings=timings)
        clock = time.perf_counter
        frame_pose = None
        if self.tracker is not None:  # the odometry sees every frame, in order, before any relative pose
            t = clock()
            frame_pose = self.tracker.track(frame, features)
            timings["poses"] = clock() - t
        t = clock()
        spec = self.settings.points
        if self.points is not None:
            points = self.points.process(frame, features, frame_pose)
        else:
            gt = frame.gt_depth()
            if gt is None:
                points = PointsOutcome(FrameStatus.TOO_FEW_POINTS, f"--points {spec} needs ground-truth depth")
            else:
                uv, depth = spec.sample(gt, frame.index)
                points = PointsOutcome(FrameStatus.OK, "", uv=uv, depth=depth)
        timings["points"] = clock() - t
        timings.update(points.timings)

        result = FrameResult(frame.index, frame.stem, frame.timestamp, points.status, points.reason, spec, points,
                             timings=timings, frame_pose=frame_pose)
        if disparity is None:
            result.status = FrameStatus.NO_DISPARITY
            result.reason = missing_disparity_reason(self.disparity_source, frame)  # names a missing file
            log.debug("frame %d: no disparity map", frame.index)
            return result

        t = clock()
        result.disparity = disparity
        content = check_map_content(disparity, self.settings.disparity.min_valid_fraction)
        result.disparity_valid_fraction = content.valid_fraction
        d, inside = sample_bilinear(disparity, points.uv)
        rs = self.settings.rescaler
        if rs.max_disparity_spread is not None and len(points.uv):  # points on depth edges: not fitted
            inside &= disparity_spread(disparity, points.uv, rs.spread_radius_px) <= rs.max_disparity_spread
        result.points_sampled = int(inside.sum())
        result.points_uv, result.points_depth = points.uv[inside], points.depth[inside]
        result.points_sigma = None if points.sigma is None else points.sigma[inside]
        # an unusable map gets no fit and no fallback: any depth from it would be wrong
        usable = content if not content.ok else check_inversion(d[inside], points.depth[inside])
        if not usable.ok:
            outcome = self.rescaler.skip(f"unusable disparity map: {usable.reason}")
        else:
            outcome = self.rescaler.update(d[inside], points.depth[inside], result.points_sigma,
                                           None if points.confidence is None else points.confidence[inside],
                                           disparity_map=disparity,
                                           depth_shared=None if points.depth_shared is None
                                           else points.depth_shared[inside])
        timings["fit"] = clock() - t
        result.rescale = outcome
        own = outcome.scale_only if outcome.scale_only is not None and outcome.scale_only.ok else outcome.raw
        result.points_inlier = own.inliers if len(own.inliers) == len(result.points_depth) else None
        result.status = decide_frame_status(points.status, outcome.source, outcome.raw.status, usable.ok)
        if not usable.ok:
            result.reason = outcome.reason
        elif result.status.has_depth or points.status == FrameStatus.OK:
            result.reason = "; ".join(r for r in (points.reason, outcome.reason) if r)
        if usable.ok and content.valid_fraction < 1.0:
            result.reason = f"{result.reason}; disparity valid on {content.valid_fraction:.0%} of the image" \
                .lstrip("; ")
        if outcome.fit is not None:
            t = clock()
            result.depth = outcome.metric_depth(disparity)
            timings["depth"] = clock() - t
        log.debug("frame %d: %s (%s)", frame.index, result.status.value, result.reason)
        return result

