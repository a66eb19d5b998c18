"""The records a run writes: one :class:`FrameRecord` per frame and one :class:`RunHeader` per run.

``frames.jsonl`` holds the header on its first line (``"record": "run"``) and then one
frame record per line (``"record": "frame"``), in frame order. The schema of both is
documented field by field in docs/frames_schema.md; :func:`frame_record` is the only
place a frame record is built.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from vio_core.errors import InputError

from ..evaluation import FrameEvaluation
from ..pipeline import FrameResult

#: version of the record layout (bumped when a field changes meaning)
RECORD_SCHEMA_VERSION = 2


def _round(x: float | None, digits: int | None = None) -> float | None:
    """``x`` rounded to ``digits`` (None: as is), or None when missing or not finite."""
    if x is None or not math.isfinite(x):
        return None
    return float(x) if digits is None else round(float(x), digits)


@dataclass
class FrameRecord:
    """One line of ``frames.jsonl``: what happened to one frame (docs/frames_schema.md).

    Optional fields are None when they do not apply and are then left out of the JSON.
    """

    frame: int
    stem: str
    timestamp: float
    status: str
    reason: str
    point_source: str
    partner_keyframe: int | None = None
    partners: list[int] | None = None
    weak_pair: bool | None = None
    pair_rotation_deg: float | None = None
    pair_translation_m: float | None = None
    matches: int = 0
    triangulated_points: int = 0
    point_status: dict[str, int] | None = None
    keyframe: bool | None = None
    keyframe_reason: str | None = None
    landmarks_associated: int | None = None
    window_residual_px: float | None = None
    pose_shift_sigmas: float | None = None
    points_sampled: int = 0
    inliers: int = 0
    alpha: float | None = None
    beta: float | None = None
    sigma_alpha: float | None = None
    sigma_beta: float | None = None
    r2: float | None = None
    fit_source: str | None = None
    fit_diagnostics: dict[str, Any] | None = None
    abs_rel: float | None = None
    delta1: float | None = None
    oracle_abs_rel: float | None = None
    points_evaluated: int | None = None
    points_rel_err_median: float | None = None
    points_rel_err_p90: float | None = None
    points_rel_err_bias: float | None = None
    backfilled: bool | None = None
    disparity_valid_fraction: float | None = None
    predicted_error: float | None = None
    predicted_abs_rel: float | None = None
    predicted_pose_error: float | None = None
    rescale_abs_rel: float | None = None
    pose_sigma_rotation_deg: float | None = None
    pose_sigma_translation_m: float | None = None
    pose_inflation: float | None = None
    pose_chi2: float | None = None
    pair_scale_log_ratio: float | None = None
    pair_scale_sigma: float | None = None
    pose_status: str | None = None
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON object: the core fields always (null when missing), optional ones only when set."""
        out: dict[str, Any] = {"record": "frame"}
        out.update({k: v for k, v in asdict(self).items() if v is not None or k in _CORE_FIELDS})
        return out


#: fields present in every frame record (null when they do not apply)
_CORE_FIELDS = frozenset({"frame", "stem", "timestamp", "status", "reason", "point_source", "partner_keyframe",
                          "matches", "triangulated_points", "points_sampled", "inliers", "alpha", "beta", "r2",
                          "fit_source", "seconds", "timings"})


def frame_record(result: FrameResult, evaluation: FrameEvaluation | None = None) -> FrameRecord:
    """The frame record of a pipeline result and, when ground truth exists, its evaluation."""
    points = result.points
    rec = FrameRecord(
        frame=result.frame,
        stem=result.stem,
        timestamp=result.timestamp,
        status=result.status.value,
        reason=result.reason,
        point_source=str(result.point_source),
        partner_keyframe=points.partners[0] if points.partners else None,
        partners=points.partners if len(points.partners) > 1 else None,
        weak_pair=True if points.weak else None,
        matches=points.matches,
        triangulated_points=int(len(points.depth)),
        point_status=points.point_status or None,
        points_sampled=result.points_sampled,
        backfilled=True if result.backfilled else None,
        disparity_valid_fraction=(None if result.disparity_valid_fraction is None
                                  or result.disparity_valid_fraction >= 1.0
                                  else round(result.disparity_valid_fraction, 5)),
        pose_status=None if result.frame_pose is None else result.frame_pose.status or None,
        seconds=round(result.seconds, 4),
        timings={k: round(v, 5) for k, v in result.timings.items()},
    )
    if points.landmarks is not None:
        info = points.landmarks
        rec.keyframe = info.keyframe
        rec.keyframe_reason = info.keyframe_reason or None
        rec.landmarks_associated = info.associated
        rec.window_residual_px = _round(info.window_residual_px, 3)
        rec.pose_shift_sigmas = _round(info.pose_shift_sigmas, 3)
    if points.attempts and points.attempts[0].pose_sigma is not None:
        rec.pose_sigma_rotation_deg = _round(points.attempts[0].pose_sigma[0], 5)
        rec.pose_sigma_translation_m = _round(points.attempts[0].pose_sigma[1], 6)
    rec.pose_inflation = _round(points.pose_inflation, 3)
    tested = [a.consistency.chi2 for a in points.attempts if a.consistency is not None and a.consistency.tested]
    rec.pose_chi2 = _round(max(tested), 3) if tested else None
    if points.scale_agreement is not None:
        rec.pair_scale_log_ratio = _round(points.scale_agreement[0], 5)
        rec.pair_scale_sigma = _round(points.scale_agreement[1], 5)
    if points.motion is not None:
        rec.pair_rotation_deg = round(points.motion.rotation_deg, 3)
        rec.pair_translation_m = round(points.motion.translation_m, 4)
    if result.rescale is not None:
        out = result.rescale
        rec.inliers = int(out.n_inliers)
        rec.fit_source = out.source.value
        rec.fit_diagnostics = out.raw.to_json()
        if out.predicted_error is not None:
            rec.predicted_error = _round(out.predicted_error, 5)
        rec.predicted_abs_rel = _round(out.predicted_abs_rel, 5)
        rec.predicted_pose_error = _round(out.predicted_pose_error, 5)
        if out.fit is not None:
            rec.alpha, rec.beta = float(out.fit.alpha), float(out.fit.beta)
            rec.sigma_alpha, rec.sigma_beta = _round(out.fit.sigma_alpha), _round(out.fit.sigma_beta)
            rec.r2 = _round(out.fit.r2)
    if evaluation is not None:
        if evaluation.metrics is not None:
            rec.abs_rel = _round(evaluation.metrics.abs_rel, 5)
            rec.delta1 = _round(evaluation.metrics.delta1, 5)
        if evaluation.oracle is not None:
            rec.oracle_abs_rel = _round(evaluation.oracle.abs_rel, 5)
        rec.rescale_abs_rel = _round(evaluation.rescale_abs_rel, 5)
        if evaluation.points is not None:
            acc = evaluation.points
            rec.points_evaluated = int(acc.count)
            rec.points_rel_err_median = None if acc.count == 0 else _round(acc.median, 5)
            rec.points_rel_err_p90 = None if acc.count == 0 else _round(acc.p90, 5)
            rec.points_rel_err_bias = None if acc.count == 0 else _round(acc.bias, 5)
    return rec


@dataclass
class RunHeader:
    """The first line of ``frames.jsonl`` (and the ``run`` block of ``metrics.json``).

    Attributes:
        vio_depth_version: the package version that wrote the run.
        command: the command line (``sys.argv``), or None when run from Python.
        sequence: the sequence's folder, format and name.
        settings: the full pipeline and run settings (``vio-depth config --dump`` form).
        disparity_kind: ``files``, ``simulated``, ``model`` or ``array``: a SIMULATED
            disparity is labelled as such.
    """

    vio_depth_version: str
    command: list[str] | None
    sequence: dict[str, Any]
    settings: dict[str, Any]
    disparity_kind: str
    schema_version: int = RECORD_SCHEMA_VERSION

    def to_json(self) -> dict[str, Any]:
        return {"record": "run", **asdict(self)}


def read_frames_jsonl(path) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """``(header, frame records)`` of a ``frames.jsonl`` (header None for files without one,
    written before the header existed).

    Raises:
        InputError: missing file or a line that is not JSON (names file and line).
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    header, frames = None, []
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}:{lineno}: not JSON ({exc.msg})") from None
        if obj.get("record") == "run":
            header = obj
        else:
            frames.append(obj)
    return header, frames
