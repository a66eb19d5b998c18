"""The streaming pipeline: frame -> features -> points -> fit -> metric depth.

One :class:`Pipeline` processes frames in order (``process(frame)``). Every per-frame
failure is a :class:`~vio_depth.pipeline.FrameStatus` with a reason; nothing in here raises
for a bad frame (only for bad *input*, e.g. an unreadable image).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

from matchers import Features, Matcher, create_matcher
from vio_core.errors import SettingsError

from ..disparity import DisparitySource, check_inversion, check_map_content, create_disparity_source
from ..evaluation import PointSourceKind
from ..frame import Frame
from ..poses import GroundTruthPoses, PoseSource, create_pose_source
from ..rescale import Rescaler, sample_bilinear
from .landmark_points import LandmarkPointsStage
from .points import TwoViewPoints
from .result import FrameResult, PointsOutcome, PreparedFrame
from .settings import PipelineSettings
from .status import FrameStatus, decide_frame_status

log = logging.getLogger(__name__)


class Pipeline:
    """Streaming metric-depth pipeline over the frames of one camera.

    Args:
        settings: see :class:`PipelineSettings`.
        pose_source: relative poses between frames; default: built from ``settings.poses``
            for ``sequence`` (the ``gt`` source needs none).
        disparity_source: each frame's affine-invariant disparity; default: built from
            ``settings.disparity`` for ``sequence``.
        sequence: the sequence the frames come from, when the default sources need it
            (IMU samples, the disparity it carries).
        matcher: a ready matcher instead of one built from ``settings.matcher``.
    """

    def __init__(self, settings: PipelineSettings | None = None, pose_source: PoseSource | None = None,
                 disparity_source: DisparitySource | None = None, *, sequence=None, matcher: Matcher | None = None):
        self.settings = settings = PipelineSettings() if settings is None else settings
        self.sequence = sequence
        self.pose_source = create_pose_source(settings.poses, sequence) if pose_source is None else pose_source
        self.disparity_source = (create_disparity_source(settings.disparity, sequence)
                                 if disparity_source is None else disparity_source)
        self.rescaler = Rescaler(settings.rescaler)
        self.points = None
        if settings.points.kind == PointSourceKind.SFM:
            matcher = create_matcher(settings.matcher) if matcher is None else matcher
            self.points = TwoViewPoints(matcher, self.pose_source, settings.pairing, settings.triangulation,
                                        settings.min_matches)
        elif settings.points.kind == PointSourceKind.LANDMARKS:
            if not isinstance(self.pose_source, GroundTruthPoses):
                raise SettingsError("--points landmarks takes the sequence's poses as priors (--poses gt); "
                                    f"the {self.pose_source.name!r} pose source gives relative poses only")
            matcher = create_matcher(settings.matcher) if matcher is None else matcher
            self.points = LandmarkPointsStage(matcher, settings.landmarks.resolved(getattr(sequence, "pose_kind",
                                                                                           "mocap")))

    @property
    def matcher(self) -> Matcher | None:
        return None if self.points is None else self.points.matcher

    def fresh(self) -> "Pipeline":
        """A new pipeline with the same settings, sources and matcher, and no history."""
        return Pipeline(self.settings, self.pose_source, self.disparity_source, sequence=self.sequence,
                        matcher=self.matcher)

    # ------------------------------------------------------------------ per frame
    def process(self, frame: Frame) -> FrameResult:
        """Process the next frame of the stream and return its result (with ``depth``)."""
        return self.process_prepared(self.prepare(frame))

    def prepare(self, frame: Frame, features: Features | None = None) -> PreparedFrame:
        """The frame's stateless stages: image decoding, features, disparity.

        They read nothing of the pipeline's state (keyframes, filter), so frames may be
        prepared ahead of :meth:`process_prepared`, in other threads (several at once when
        the matcher's ``concurrent_extract`` is true: SIFT keeps one detector per thread). ``features``: this
        frame's features extracted earlier by the same matcher (the image is then not read
        here).
        """
        timings: dict[str, float] = {}
        clock = time.perf_counter
        if self.points is not None and features is None:
            t = clock()
            image = frame.image()  # read once: a model disparity source gets the same pixels
            frame = replace(frame, load_image=lambda: image)
            timings["image"] = clock() - t
            t = clock()
            features = self.points.matcher.extract(image)  # once per frame, kept if keyframe
            timings["features"] = clock() - t
        t = clock()
        disparity = self.disparity_source(frame)
        timings["disparity"] = clock() - t
        return PreparedFrame(frame, features, disparity, timings)

    def process_prepared(self, prepared: PreparedFrame) -> FrameResult:
        """The stateful stages of a :meth:`prepare`-d frame, in stream order: pairing,
        triangulation, fit, depth. ``process(frame)`` is ``process_prepared(prepare(frame))``."""
        frame, features, disparity = prepared.frame, prepared.features, prepared.disparity
        timings = dict(prepared.timings)
        clock = time.perf_counter
        t = clock()
        spec = self.settings.points
        if self.points is not None:
            points = self.points.process(frame, features)
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
                             timings=timings)
        if disparity is None:
            result.status, result.reason = FrameStatus.NO_DISPARITY, "no disparity map for this frame"
            log.debug("frame %d: no disparity map", frame.index)
            return result

        t = clock()
        result.disparity = disparity
        content = check_map_content(disparity, self.settings.disparity.min_valid_fraction)
        result.disparity_valid_fraction = content.valid_fraction
        d, inside = sample_bilinear(disparity, points.uv)
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
                                           disparity_map=disparity)
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

