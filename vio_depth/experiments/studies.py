"""Robustness studies like the paper's figure: one perturbation swept, the depth metrics at each value.

Each study (:data:`~vio_depth.evaluation.STUDIES`) is one task per sequence
(:func:`run_study_task`, task variant ``study:<name>``), on a block of evaluated frames
of the entry (``--study-frames``, :func:`~.command.study_frames`). Draws are seeded with ``(seed, frame index)``, the same
at every value of a sweep, so a curve shows the perturbation's size, not new luck.

==============  ============================  =======================================================
study           points                        perturbation, and who is compared
==============  ============================  =======================================================
``depth_noise``  16 LiDAR beams from the       relative Gaussian noise on their depths; the three fits
                 ground truth                  of :data:`~.fits.FIT_METHODS` on the same points
``pixel_shift``  16 beams                      every point moved by S px in one random direction per
                                               frame (calibration error); three fits
``lidar_beams``  N beams                       N = 1 .. 64; three fits
``outliers``     our triangulated points       a fraction replaced by depths wrong by >= 25 %
                 (``sfm``)                     (log-uniform in ``[cap/200, cap]``); three fits
``imu_noise``    ``sfm`` with IMU poses        IMU noise densities x s (and matching noise added);
                                               our pipeline (sequences with an IMU only)
``pose_noise``   ``sfm`` / paper-reference     per-frame pose errors (rotation sigma, 0.1 m per
                                               degree of translation sigma); our pipeline and the
                                               paper-reference on the perturbed poses
==============  ============================  =======================================================
"""

from __future__ import annotations

import time

import numpy as np

from ..baselines import iter_paper_reference, paper_reference_preset
from ..evaluation import (
    STUDIES,
    ImuNoiseBoost,
    PerturbedSequence,
    PoseNoise,
    Study,
    add_outliers,
    compute_metrics,
    depth_noise,
    lidar_points,
    shift_pixels,
)
from ..rescale import sample_bilinear
from .context import FrameRange, TaskContext, open_task
from .fits import FIT_METHODS, fit_and_depth
from .runner import TimedSource, pipeline_settings, run_stream
from .tasks import Task
from .variants import Variant, VariantKind

#: beams of the reference points of the depth-noise and pixel-shift studies
REFERENCE_BEAMS = 16
POINT_STUDIES = ("depth_noise", "pixel_shift", "lidar_beams", "outliers")
PIPELINE_STUDIES = ("imu_noise", "pose_noise")


def _metrics(depth, gt, ctx: TaskContext) -> dict:
    """``{"has_depth", "delta1", "abs_rel", "rmse"}`` of one depth map (or of none)."""
    if depth is None or gt is None:
        return {"has_depth": False}
    m = compute_metrics(depth, gt, ctx.mask.min_depth, ctx.mask.max_depth)
    if m.n_pixels == 0:
        return {"has_depth": False}
    return {"has_depth": True, "delta1": m.delta1, "abs_rel": m.abs_rel, "rmse": m.rmse}


def _perturbed_points(study: Study, params: dict, uv, z, gt_raw, seed, ctx: TaskContext):
    if study.name == "depth_noise":
        return uv, depth_noise(z, params["rel_sigma"], seed)
    if study.name == "pixel_shift":
        return shift_pixels(uv, params["shift_px"], seed), z
    if study.name == "lidar_beams":
        return lidar_points(gt_raw, int(params["n_beams"]))
    hi = ctx.mask.max_depth
    return uv, add_outliers(z, params["ratio"], seed, hi / 200.0, hi).depth


def _sweep_frame(study: Study, ctx: TaskContext, index: int, disparity, uv, z, gt_raw) -> list[dict]:
    """Every (value, method) of a point study on one frame: a list of metric dicts, value-major."""
    gt = ctx.mask.apply(gt_raw)
    out = []
    for params in study.values:
        p_uv, p_z = _perturbed_points(study, params, uv, z, gt_raw, [ctx.seed, index], ctx)
        d, inside = sample_bilinear(disparity, p_uv)
        for method in FIT_METHODS:
            depth, _ = fit_and_depth(method, disparity, d[inside], np.asarray(p_z)[inside], seed=ctx.seed)
            out.append(_metrics(depth, gt, ctx))
    return out


def _point_study(study: Study, ctx: TaskContext, source) -> tuple[list[str], list[list[dict]]]:
    """Per evaluated frame, the sweep of a point study (methods: the three fits)."""
    per_frame = []
    if study.name == "outliers":
        variant = Variant(VariantKind.SFM, matcher="sift", poses="gt")

        def on_frame(frame, res):
            if res.disparity is None or res.points_uv is None or len(res.points_uv) == 0:
                return [{"has_depth": False}] * (len(study.values) * len(FIT_METHODS))
            return _sweep_frame(study, ctx, frame.index, res.disparity, res.points_uv, res.points_depth,
                                frame.gt_depth())

        values, _ = run_stream(ctx, source, pipeline_settings(variant, ctx.settings["pairing"], ctx.seed), on_frame)
        per_frame = [values[i] for i in ctx.evaluate]
    else:
        for i in ctx.evaluate:
            frame = ctx.sequence[i]
            disparity, gt_raw = source(frame), frame.gt_depth()
            if disparity is None or gt_raw is None:
                per_frame.append([{"has_depth": False}] * (len(study.values) * len(FIT_METHODS)))
                continue
            base = lidar_points(gt_raw, REFERENCE_BEAMS)
            per_frame.append(_sweep_frame(study, ctx, i, disparity, base.uv, base.depth, gt_raw))
    return list(FIT_METHODS), per_frame


def _pipeline_study(study: Study, ctx: TaskContext, source) -> tuple[list[str], list[list[dict]]]:
    """Per evaluated frame, the sweep of a study that perturbs the pipeline's inputs."""
    imu = study.name == "imu_noise"
    methods = ["ours (IMU poses)"] if imu else ["ours", "paper-reference"]
    variant = Variant(VariantKind.SFM, matcher="sift", poses="imu" if imu else "gt")
    settings = pipeline_settings(variant, ctx.settings["pairing"], ctx.seed)
    per_value = []
    for params in study.values:
        pert = PerturbedSequence(ctx.sequence, ctx.seed,
                                 imu_noise=ImuNoiseBoost(params["noise_scale"]) if imu else None,
                                 pose_noise=None if imu else PoseNoise(params["rot_sigma_deg"], params["trans_sigma_m"]))
        frames = FrameRange(pert, ctx.frames.start, ctx.frames.stop)
        ours, _ = run_stream(ctx, source, settings, lambda f, r: _metrics(r.depth, ctx.gt(f), ctx), frames=frames)
        cols = [[ours[i]] for i in ctx.evaluate]
        if not imu:
            preset = paper_reference_preset(ctx.settings["paper"], seed=ctx.seed)
            for k, res in enumerate(iter_paper_reference(pert, source, preset, ctx.evaluate)):
                cols[k].append(_metrics(res.depth, ctx.gt(pert[res.frame]) if res.has_depth else None, ctx))
        per_value.append(cols)
    per_frame = [[m for v in range(len(study.values)) for m in per_value[v][k]] for k in range(len(ctx.evaluate))]
    return methods, per_frame


def _rows(study: Study, methods: list[str], per_frame: list[list[dict]]) -> list[dict]:
    rows = []
    for v, x in enumerate(study.x()):
        for j, method in enumerate(methods):
            cells = [f[v * len(methods) + j] for f in per_frame]
            ok = [c for c in cells if c["has_depth"]]
            row = {"method": method, "value": x, "frames": len(cells), "frames_with_depth": len(ok),
                   "coverage": len(ok) / len(cells) if cells else None}
            for k in ("delta1", "abs_rel", "rmse"):
                row[k] = float(np.mean([c[k] for c in ok])) if ok else None
            rows.append(row)
    return rows


def run_study(ctx: TaskContext, name: str) -> dict:
    """Run study ``name`` on ``ctx``: ``{"study", "parameter", "unit", "rows", "skipped", "seconds"}``.

    ``rows``: one per (value, method) with frames, frames_with_depth, coverage and the
    frame-averaged delta1 / AbsRel / RMSE; ``skipped`` says why a study does not apply
    (e.g. no IMU), else None.
    """
    study = STUDIES[name]
    out = {"study": name, "parameter": study.parameter, "unit": study.unit, "rows": [], "skipped": None}
    if name == "imu_noise" and ctx.sequence.imu is None:
        out["skipped"] = "the sequence has no IMU"
        return out
    source = TimedSource(ctx.disparity)
    t = time.perf_counter()
    methods, per_frame = (_point_study if name in POINT_STUDIES else _pipeline_study)(study, ctx, source)
    out["rows"] = _rows(study, methods, per_frame)
    out["seconds"] = time.perf_counter() - t
    return out


def run_study_task(task: Task) -> dict:
    """Runner of :func:`~vio_depth.experiments.tasks.run_tasks` for ``study:<name>`` tasks."""
    ctx = open_task(task.sequence, dict(task.settings))
    name = task.variant.partition(":")[2]
    out = run_study(ctx, name)
    out.update(label=ctx.settings.get("label", ""), sequence=task.sequence)
    return out
