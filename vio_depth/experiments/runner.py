"""The task runner of ``vio-depth eval``: one variant on one sequence -> a row of ``results.csv``.

:func:`run_variant_task` is the module-level runner handed to
:func:`~vio_depth.experiments.tasks.run_tasks` (workers import it). Each variant of
:mod:`.variants` scores the same evaluated frames (:class:`~.context.TaskContext`):

* ``oracle`` and ``fixed`` read only the evaluated frames;
* ``lidar:N``, ``sfm`` and ``sfm-no-ransac`` run our streaming pipeline over the whole
  processed range in order (with the offline backfill of ``vio-depth run``) and score the
  evaluated frames as they pass;
* ``paper-reference`` processes the evaluated frames, pairing each with any earlier frame
  of the sequence as the published code does.

Results are plain JSON (:func:`run_variant_task`'s return value), so they are identical
whichever executor ran them; only ``seconds_per_frame`` is a timing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from vio_core.settings import override

from ..baselines import iter_paper_reference, paper_reference_preset
from ..evaluation import compute_metrics, oracle_fit, point_depth_errors
from ..frame import Frame
from ..pipeline import FrameResult, FrameStatus, Pipeline, PipelineSettings, build_matcher, build_pose_stage
from ..rescale import metric_depth, sample_bilinear
from ..run import backfill_leading_frames
from .context import TaskContext, open_task
from .fits import PooledSums, least_squares_fit
from .scores import FrameScore, aggregate, score_metrics
from .tasks import Task
from .variants import Variant, VariantKind, parse_variant


class TimedSource:
    """A disparity source that adds the seconds spent in it to ``seconds`` (to leave them out of a
    variant's own time)."""

    def __init__(self, source):
        self.source = source
        self.kind = source.kind
        self.seconds = 0.0

    def __call__(self, frame: Frame):
        t = time.perf_counter()
        try:
            return self.source(frame)
        finally:
            self.seconds += time.perf_counter() - t


def _point_error(uv, depth, gt_raw) -> float | None:
    if uv is None or len(uv) == 0 or gt_raw is None:
        return None
    acc = point_depth_errors(uv, depth, gt_raw)
    return acc.median if acc.count else None


# ----------------------------------------------------------------------------- oracle, fixed
def _oracle(ctx: TaskContext, source: TimedSource, variant: Variant) -> tuple[list[FrameScore], float, int]:
    lo, hi = ctx.mask.min_depth, ctx.mask.max_depth
    scores, busy = [], 0.0
    for i in ctx.evaluate:
        frame = ctx.sequence[i]
        d = source(frame)
        gt = ctx.gt(frame)
        if d is None or gt is None:
            scores.append(FrameScore(i, "no_disparity" if d is None else "no_ground_truth", False))
            continue
        t = time.perf_counter()
        fit = oracle_fit(d, gt, lo, hi)
        depth = metric_depth(d, fit) if fit.ok else None
        busy += time.perf_counter() - t
        if depth is None:
            scores.append(FrameScore(i, fit.status.value, False))
            continue
        m = compute_metrics(depth, gt, lo, hi)
        scores.append(FrameScore(i, "ok", True, **score_metrics(m), r2=fit.r2))
    return scores, busy, len(ctx.evaluate)


def _fixed(ctx: TaskContext, source: TimedSource, variant: Variant) -> tuple[list[FrameScore], float, int]:
    lo, hi = ctx.mask.min_depth, ctx.mask.max_depth
    pooled = PooledSums(lo, hi)
    busy = 0.0
    for i in ctx.evaluate:  # pass 1: one least squares over every evaluated frame's ground truth
        frame = ctx.sequence[i]
        d, gt = source(frame), ctx.gt(frame)
        if d is not None and gt is not None:
            t = time.perf_counter()
            pooled.add(d, gt)
            busy += time.perf_counter() - t
    fit = pooled.fit()
    scores = []
    for i in ctx.evaluate:  # pass 2: that one (alpha, beta) on every frame
        frame = ctx.sequence[i]
        d, gt = source(frame), ctx.gt(frame)
        if d is None or gt is None or not fit.ok:
            scores.append(FrameScore(i, fit.status.value if d is not None else "no_disparity", False))
            continue
        t = time.perf_counter()
        depth = metric_depth(d, fit)
        busy += time.perf_counter() - t
        m = compute_metrics(depth, gt, lo, hi)
        scores.append(FrameScore(i, "ok", True, **score_metrics(m), r2=fit.r2))
    return scores, busy, len(ctx.evaluate)


# ----------------------------------------------------------------------------- our pipeline
def pipeline_settings(variant: Variant, pairing: str, seed: int = 0) -> PipelineSettings:
    """Our pipeline's settings for a ``lidar:N`` / ``sfm`` / ``sfm-no-ransac`` variant (defaults
    otherwise: the streaming rescaler, as ``vio-depth run``)."""
    if variant.kind == VariantKind.LIDAR:
        s = PipelineSettings.from_presets(pairing=pairing, points=f"lidar:{variant.beams}")
    else:
        s = PipelineSettings.from_presets(matcher=variant.matcher, poses=variant.poses, pairing=pairing)
    return override(s, {"rescaler": {"ransac": {"seed": int(seed)}}})


@dataclass(frozen=True)
class _Outcome:
    """What the backfill needs of a forward result (the depth maps are not kept)."""

    has_depth: bool
    status: FrameStatus


def _score_result(ctx: TaskContext, frame: Frame, res: FrameResult, variant: Variant) -> FrameScore:
    gt_raw = frame.gt_depth()
    gt = None if gt_raw is None else ctx.mask.apply(gt_raw)
    lo, hi = ctx.mask.min_depth, ctx.mask.max_depth
    n_points = res.points_sampled if res.points_uv is not None else len(res.points.depth)
    perr = None if variant.kind == VariantKind.LIDAR else _point_error(res.points_uv, res.points_depth, gt_raw)
    if variant.kind == VariantKind.SFM_NO_RANSAC:  # the same points, plain least squares
        if res.disparity is None or res.points_uv is None:
            return FrameScore(frame.index, res.status.value, False, points=n_points, point_error=perr)
        d, _ = sample_bilinear(res.disparity, res.points_uv)
        fit = least_squares_fit(d, res.points_depth)
        if not fit.ok or gt is None:
            return FrameScore(frame.index, fit.status.value, False, points=n_points, point_error=perr)
        m = compute_metrics(metric_depth(res.disparity, fit), gt, lo, hi)
        return FrameScore(frame.index, "ok", True, **score_metrics(m), r2=fit.r2, points=n_points, point_error=perr)
    m = None if res.depth is None or gt is None else compute_metrics(res.depth, gt, lo, hi)
    fit = res.fit
    return FrameScore(frame.index, res.status.value, res.has_depth, **score_metrics(m),
                      r2=None if fit is None else fit.r2, points=n_points, point_error=perr)


def variant_pipeline(settings: PipelineSettings, frames, source) -> Pipeline:
    """The pipeline of ``settings`` over ``frames`` (a :class:`~.context.FrameRange`) with the
    disparity ``source``.

    The pose source is built for the whole sequence (``frames.base``: the IMU source looks up
    neighbouring frames by their index in it) with the settings' matcher, which a tracking
    source (``vio``) shares with the pipeline: its features are extracted once, by the
    variant's matcher (before, the odometry always got SIFT, whatever the variant's matcher).
    """
    matcher = build_matcher(settings)
    poses = build_pose_stage(settings.poses, frames.base, matcher)
    return Pipeline(settings, pose_source=poses, disparity_source=source, sequence=frames, matcher=matcher)


def run_stream(ctx: TaskContext, source, settings: PipelineSettings, on_frame, frames=None):
    """Our pipeline over the processed range in order, then the backfill of ``vio-depth run``.

    Args:
        ctx: the task.
        source: the disparity source (a :class:`TimedSource`).
        settings: the pipeline's settings.
        on_frame: ``on_frame(frame, result)`` for every evaluated frame, as it passes (again
            for a frame the backfill gave depth later); its return values are collected.
        frames: the processed frames (default ``ctx.frames``; e.g. a perturbed range).

    Returns:
        ``({frame index: last on_frame value}, seconds)``: the pipeline's wall time (forward
        and backward passes) without the disparity source and without ``on_frame``.
    """
    frames = ctx.frames if frames is None else frames
    before = source.seconds
    pipeline = variant_pipeline(settings, frames, source)
    wanted = set(ctx.evaluate)
    values: dict[int, object] = {}
    outcomes: dict[int, _Outcome] = {}
    busy = 0.0
    for pos in range(len(frames)):
        t = time.perf_counter()
        frame = frames[pos]
        res = pipeline.process(frame)
        busy += time.perf_counter() - t
        outcomes[pos] = _Outcome(res.has_depth, res.status)
        if frame.index in wanted:
            values[frame.index] = on_frame(frame, res)
    t = time.perf_counter()
    back = backfill_leading_frames(frames, pipeline, outcomes, len(frames))
    busy += time.perf_counter() - t
    for _, (frame, res) in back.items():
        if frame.index in wanted:
            values[frame.index] = on_frame(frame, res)
    return values, busy - (source.seconds - before)


def _pipeline(ctx: TaskContext, source: TimedSource, variant: Variant) -> tuple[list[FrameScore], float, int]:
    settings = pipeline_settings(variant, ctx.settings["pairing"], ctx.seed)
    scores, seconds = run_stream(ctx, source, settings, lambda f, r: _score_result(ctx, f, r, variant))
    return [scores[i] for i in ctx.evaluate], seconds, len(ctx.frames)


# ----------------------------------------------------------------------------- the published code
def _paper_reference(ctx: TaskContext, source: TimedSource, variant: Variant) -> tuple[list[FrameScore], float, int]:
    settings = paper_reference_preset(ctx.settings["paper"], seed=ctx.seed)
    lo, hi = ctx.mask.min_depth, ctx.mask.max_depth
    scores, busy = [], 0.0
    for res in iter_paper_reference(ctx.sequence, source, settings, ctx.evaluate):
        busy += res.seconds - res.seconds_disparity
        frame = ctx.sequence[res.frame]
        gt_raw = frame.gt_depth() if res.has_depth or res.points else None
        perr = _point_error(res.points_uv, res.points_depth, gt_raw)
        if not res.has_depth or gt_raw is None:
            scores.append(FrameScore(res.frame, res.status.value, False, points=res.points, point_error=perr))
            continue
        m = compute_metrics(res.depth, ctx.mask.apply(gt_raw), lo, hi)
        scores.append(FrameScore(res.frame, "ok", True, **score_metrics(m), r2=res.r2, points=res.points,
                                 point_error=perr))
    return scores, busy, len(ctx.evaluate)


_RUNNERS = {
    VariantKind.ORACLE: _oracle,
    VariantKind.FIXED: _fixed,
    VariantKind.LIDAR: _pipeline,
    VariantKind.SFM: _pipeline,
    VariantKind.SFM_NO_RANSAC: _pipeline,
    VariantKind.PAPER_REFERENCE: _paper_reference,
}


def evaluate_variant(ctx: TaskContext, variant: Variant) -> dict:
    """Score ``variant`` on ``ctx``: ``{"row": aggregate, "frames": [FrameScore JSON], "disparity_kind"}``.

    The row's ``seconds_per_frame`` is the variant's own wall time (without the disparity
    source and without scoring) over the frames it processed.
    """
    source = TimedSource(ctx.disparity)
    scores, seconds, processed = _RUNNERS[variant.kind](ctx, source, variant)
    kind = getattr(source.kind, "value", str(source.kind))
    return {"row": aggregate(scores, max(seconds, 0.0), processed), "frames": [s.to_json() for s in scores],
            "disparity_kind": kind}


def run_variant_task(task: Task) -> dict:
    """Runner of :func:`~vio_depth.experiments.tasks.run_tasks`: ``task.variant`` on ``task.sequence``."""
    ctx = open_task(task.sequence, dict(task.settings))
    variant = parse_variant(task.variant)
    out = evaluate_variant(ctx, variant)
    out.update(variant=variant.name, label=ctx.settings.get("label", ""), sequence=task.sequence)
    return out
