"""What a whole run did: :class:`RunSummary` (``metrics.json``) and the printed table."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from .record import read_frames_jsonl


@dataclass
class RunSummary:
    """What a run did.

    Attributes:
        frames_in_sequence / frames_processed / frames_with_depth: counts.
        status_counts: frames per :class:`~vio_depth.pipeline.FrameStatus` value.
        metrics: row name -> frame-averaged dense metrics: the point source (``sfm``,
            ``lidar:16``...) and ``oracle``; empty without ground-truth depth.
        point_accuracy: medians over frames of the points' accuracy, or None.
        seconds: wall time of the run.
        disparity_kind: ``files``, ``simulated``, ``model`` or ``array``.
        run: the run header (version, command line, settings; :class:`~vio_depth.run.record.RunHeader`).
        trajectory: ``trajectory.tum``'s pose count and, with ground-truth poses, ATE and RPE
            (:meth:`~vio_depth.run.trajectory.TrajectoryReport.to_json`), or None.
        outputs: what the optional exports wrote (counts, notes; docs/outputs.md).
        report: path of the report's ``index.html`` when one was written, else "".
        verdict: whether the run gave enough metric depth (:class:`~vio_depth.run.verdict.RunVerdict`).
        timings: median and p90 seconds per stage, lane totals and frames per second of the
            whole run (:func:`~vio_depth.run.timing.timing_summary`).
        resumed_frames: frames replayed from an interrupted run (0: not resumed, -1: the
            finished run was already there); not written to ``metrics.json``, so a resumed
            run's file equals an uninterrupted one's.
        pose_calibration: the pose-camera calibration (time offset, camera-to-body transform,
            their 1-sigmas, whether applied and why;
            :meth:`vio_depth.poses.PoseCalibration.to_json`), or None.
    """

    frames_in_sequence: int
    frames_processed: int
    frames_with_depth: int
    status_counts: dict[str, int]
    metrics: dict[str, dict] = field(default_factory=dict)
    point_accuracy: dict | None = None
    seconds: float = 0.0
    disparity_kind: str = ""
    run: dict[str, Any] = field(default_factory=dict)
    trajectory: dict[str, Any] | None = None
    outputs: dict[str, Any] = field(default_factory=dict)
    report: str = ""
    verdict: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, Any] = field(default_factory=dict)
    resumed_frames: int = 0
    pose_calibration: dict[str, Any] | None = None

    def to_json(self) -> dict:
        out = asdict(self)
        out.pop("resumed_frames")
        return out


def summary_of_folder(out_dir) -> RunSummary:
    """The :class:`RunSummary` of a finished run folder: its ``metrics.json`` when there is
    one, else counts rebuilt from ``frames.jsonl``."""
    out_dir = Path(out_dir)
    metrics = out_dir / "metrics.json"
    if metrics.is_file():
        try:
            data = json.loads(metrics.read_text(encoding="utf-8"))
            names = {f.name for f in fields(RunSummary)}
            return RunSummary(**{k: v for k, v in data.items() if k in names})
        except (OSError, ValueError, TypeError):
            pass
    header, frames = read_frames_jsonl(out_dir / "frames.jsonl")
    counts: dict[str, int] = {}
    for f in frames:
        counts[str(f.get("status"))] = counts.get(str(f.get("status")), 0) + 1
    seq = (header or {}).get("sequence", {})
    return RunSummary(frames_in_sequence=int(seq.get("frames", len(frames))), frames_processed=len(frames),
                      frames_with_depth=sum(f.get("alpha") is not None for f in frames), status_counts=counts,
                      disparity_kind=(header or {}).get("disparity_kind", ""), run=header or {})


#: the printed table notes a metrics row whose predictions cover less than this of the evaluated pixels
COVERAGE_NOTE_BELOW = 0.99


def format_table(summary: RunSummary) -> str:
    """The printed results table: a row for the point source (``sfm``, ``lidar:16``...) and ``oracle``."""
    lines = []
    if summary.metrics:
        head = f"{'':10s} {'delta1':>8s} {'AbsRel':>8s} {'RMSE':>8s} {'frames evaluated':>17s} {'frames in sequence':>19s}"
        lines.append(head)
        for name, m in summary.metrics.items():
            lines.append(
                f"{name:10s} {m['delta1']:8.4f} {m['abs_rel']:8.4f} {m['rmse']:8.3f} "
                f"{m['n_frames']:17d} {summary.frames_in_sequence:19d}"
            )
        covered = [(name, m["coverage"]) for name, m in summary.metrics.items()
                   if name != "oracle" and m.get("coverage") is not None and m["coverage"] < COVERAGE_NOTE_BELOW]
        for name, coverage in covered:
            lines.append(f"note: {name} has depth on {coverage:.0%} of the evaluated pixels; the metrics count the "
                         "rest as max depth (e.g. NaN disparity pixels, docs/safety.md)")
    lines.append(
        f"metric depth for {summary.frames_with_depth} of {summary.frames_processed} processed frames "
        f"({summary.frames_in_sequence} in sequence); statuses: "
        + ", ".join(f"{k} {v}" for k, v in sorted(summary.status_counts.items()))
    )
    if summary.point_accuracy and summary.point_accuracy.get("frames"):
        p = summary.point_accuracy
        lines.append(
            f"triangulated points vs ground truth: median |z-z_gt|/z_gt {p['rel_err_median_of_frames']:.3f}, "
            f"p90 {p['rel_err_p90_median_of_frames']:.3f} (medians over {p['frames']} frames, "
            f"{p['points_per_frame_median']:.0f} points/frame)"
        )
    if summary.trajectory is not None:
        lines.append(_trajectory_line(summary.trajectory))
    if summary.pose_calibration and summary.pose_calibration.get("estimated"):
        lines.append(_pose_calibration_line(summary.pose_calibration))
    if summary.outputs.get("counts"):
        lines.append("also wrote: " + ", ".join(f"{k} {v}" for k, v in summary.outputs["counts"].items()))
    for note in summary.outputs.get("notes", []):
        lines.append(f"note: {note}")
    if summary.report:
        lines.append(f"report: {summary.report}")
    if summary.disparity_kind == "simulated":
        lines.append("note: the disparity of this sequence is SIMULATED (not a Depth Anything prediction)")
    return "\n".join(lines)


def _pose_calibration_line(c: dict) -> str:
    """One line: the estimated pose-camera calibration and whether the run used it."""
    def pm(value, sigma, scale, digits):
        return f"{value * scale:.{digits}f} +- " + ("?" if sigma is None else f"{sigma * scale:.{digits}f}")

    return (f"pose calibration {'applied' if c['applied'] else 'not applied'} ({c['reason'].split(':')[0]}): "
            f"time offset {pm(c['time_offset_s'], c['time_offset_sigma_s'], 1e3, 1)} ms, rotation "
            f"{pm(c['rotation_deg'], c['rotation_sigma_deg'], 1, 2)} deg, translation "
            f"{pm(c['translation_m'], c['translation_sigma_m'], 1e3, 1)} mm")


def _trajectory_line(report: dict) -> str:
    """One line: the poses in trajectory.tum and, with ground-truth poses, ATE and RPE."""
    line = f"trajectory.tum: {report['poses']} camera poses"
    ate, rpe = report.get("ate"), report.get("rpe")
    if ate is not None:
        line += (f"; ATE {ate['ate_m']['rmse']:.4f} m RMSE over {ate['ate_m']['n']} poses (SE(3)-aligned, "
                 f"no scale correction; Sim(3) scale {ate['sim3_scale']:.4f})")
    if rpe is not None:
        line += (f"; RPE per {rpe['delta_m']:g} m: {rpe['translation_m']['rmse']:.4f} m, "
                 f"{rpe['rotation_deg']['rmse']:.3f} deg RMSE ({rpe['translation_m']['n']} pairs)")
    if report.get("note"):
        line += f" ({report['note']})"
    return line
