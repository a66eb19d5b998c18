"""Run configuration files: :class:`RunSettings` and the TOML form of pipeline + run settings.

A config file (``vio-depth run --config FILE``) holds one table per pipeline stage (see
:class:`~vio_depth.pipeline.PipelineSettings`) and a ``[run]`` table; every key is optional
and overrides the defaults. ``vio-depth config --dump`` prints the complete resolved form,
which read back gives the same settings::

    [matcher]
    preset = "sift"
    ratio = 0.8

    [pairing]
    preset = "indoor"

    [run]
    max_eval_depth = 10.0
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from vio_core.errors import InputError, SettingsError
from vio_core.limits import MAX_CONFIG_BYTES, read_limited, too_large
from vio_core.settings import override, to_plain, toml_dumps, toml_loads

from ..export import ExportSettings
from ..pipeline import PipelineSettings, chooses_preset, default_matcher_preset, default_points_spec, parse_points_spec
from ..poses import PoseCalibrationSettings
from .verdict import MIN_DEPTH_FRACTION


#: values of ``RunSettings.calibrate_poses`` (``--calibrate-poses``)
CALIBRATE_POSES_CHOICES = ("auto", "off")


@dataclass(frozen=True)
class RunSettings:
    """How a sequence is run (the ``[run]`` table of a config file).

    Attributes:
        max_frames: process only the first N frames (0 = all).
        uncertainty: also write ``uncertainty/<stem>.png`` (1-sigma depth).
        min_eval_depth / max_eval_depth: metres, the ground-truth range evaluated.
        backfill: offline second chance for the frames at the start of the sequence that got
            no depth because no earlier keyframe was far enough away: after the forward pass,
            a fresh pipeline runs backwards in time from a later frame, so those frames pair
            with *later* keyframes. Only results with depth replace the forward ones; they
            are marked ``"backfilled": true``. Needs a pose source that works in both
            directions (``gt``; ``imu`` integrates forward only, so its backward pairs fail).
        rpe_delta_m: metres of path between the pose pairs of the RPE of ``trajectory.tum``
            (:mod:`vio_depth.run.trajectory`).
        export: the optional outputs (float ``.npy`` depth, previews, PLY clouds, report
            thumbnails; :class:`~vio_depth.export.ExportSettings`, docs/outputs.md).
        report: write ``report/index.html`` and ``report.md`` at the end (needs matplotlib).
        min_depth_fraction: a finished run in which fewer than this fraction of the processed
            frames got metric depth is reported as "nothing came out" (``vio-depth run``
            exits with code 3; :mod:`vio_depth.run.verdict`).
        evaluate: evaluate each frame against the sequence's ground-truth depth, when it has
            some (dense metrics, oracle, point accuracy); False skips that work
            (``--no-evaluation``).
        calibrate_poses: ``auto`` (the default): with ``--poses gt`` on poses that are not
            exact (not a rendered sample), an offline pre-pass estimates the time offset and
            camera-to-body transform between the sequence's poses and its camera and the run
            uses the corrected poses when the estimate is significant and well constrained
            (:mod:`vio_depth.poses.calibration`; ``metrics.json``'s ``pose_calibration``);
            ``off`` takes the poses as they are (``--calibrate-poses``).
        pose_calibration: how that estimate is made and judged
            (:class:`~vio_depth.poses.PoseCalibrationSettings`).
    """

    max_frames: int = 0
    uncertainty: bool = False
    min_eval_depth: float = 1e-3
    max_eval_depth: float = 80.0
    backfill: bool = True
    rpe_delta_m: float = 1.0
    export: ExportSettings = field(default_factory=ExportSettings)
    report: bool = False
    min_depth_fraction: float = MIN_DEPTH_FRACTION
    evaluate: bool = True
    calibrate_poses: str = "auto"
    pose_calibration: PoseCalibrationSettings = field(default_factory=PoseCalibrationSettings)

    def __post_init__(self):
        if self.calibrate_poses not in CALIBRATE_POSES_CHOICES:
            raise SettingsError(f"calibrate_poses must be one of {', '.join(CALIBRATE_POSES_CHOICES)}, "
                                f"got {self.calibrate_poses!r}")
        if isinstance(self.max_frames, bool) or not isinstance(self.max_frames, int) or self.max_frames < 0:
            raise SettingsError(f"max_frames must be a non-negative integer (0 = all), got {self.max_frames!r}")
        if not 0 <= self.min_eval_depth < self.max_eval_depth:
            raise SettingsError("need 0 <= min_eval_depth < max_eval_depth (metres), got "
                                f"{self.min_eval_depth!r}, {self.max_eval_depth!r}")
        if not 0.0 <= self.min_depth_fraction <= 1.0:
            raise SettingsError(f"min_depth_fraction must be in [0, 1], got {self.min_depth_fraction!r}")
        if not self.rpe_delta_m > 0:
            raise SettingsError(f"rpe_delta_m must be positive (metres), got {self.rpe_delta_m!r}")


def config_to_dict(pipeline: PipelineSettings, run: RunSettings) -> dict[str, Any]:
    """The nested plain dict of a whole configuration (pipeline tables + ``run``)."""
    return {**pipeline.to_dict(), "run": to_plain(run)}


def config_from_dict(data: Mapping[str, Any], pipeline: PipelineSettings | None = None,
                     run: RunSettings | None = None) -> tuple[PipelineSettings, RunSettings]:
    """Apply a nested plain dict (a parsed config file) on ``pipeline`` / ``run`` (default: defaults)."""
    data = dict(data)
    run_table = data.pop("run", {})
    if not isinstance(run_table, Mapping):
        raise SettingsError(f"run: expected a table, got {run_table!r}")
    return (PipelineSettings.from_dict(data, pipeline),
            override(RunSettings() if run is None else run, run_table, where="run"))


def dump_config(pipeline: PipelineSettings, run: RunSettings) -> str:
    """TOML text of a whole configuration (``vio-depth config --dump``)."""
    return toml_dumps(config_to_dict(pipeline, run))


def read_config(path) -> dict[str, Any]:
    """The parsed tables of a TOML config file.

    Raises:
        InputError: the file is missing, unreadable or larger than
            :data:`vio_core.limits.MAX_CONFIG_BYTES` (checked before reading it).
        SettingsError: invalid TOML (the file is named).
    """
    path = Path(path)
    try:
        data, size = read_limited(path, MAX_CONFIG_BYTES)
        if data is None:
            raise InputError(f"{path}: {too_large(size, MAX_CONFIG_BYTES, 'a config file')}")
        text = data.decode("utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: config file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read config file ({exc})") from None
    return toml_loads(text, str(path))  # its errors name the file


def load_config(path, pipeline: PipelineSettings | None = None,
                run: RunSettings | None = None) -> tuple[PipelineSettings, RunSettings]:
    """Read a TOML config file and apply it on ``pipeline`` / ``run`` (default: the library's
    defaults, whose matcher is sift; :func:`resolve_config` is what the command line does, with
    the matcher following the pose source).

    Raises:
        InputError: the file is missing, unreadable or too large (:func:`read_config`).
        SettingsError: invalid TOML, an unknown table or key, or an invalid value (named).
    """
    return _apply(read_config(path), pipeline, run, source=str(path))


def resolve_config(presets: Mapping[str, str], data: Mapping[str, Any] | None = None, *,
                   source: str | None = None,
                   default_matcher: str | None = None) -> tuple[PipelineSettings, RunSettings]:
    """The settings of a run from stage preset names (the command line's ``--matcher``, ``--poses``,
    ``--pairing``, ``--rescaler``) and a parsed config file ``data`` that refines them.

    A preset named in ``presets`` is chosen before the file is applied, so that the file's table
    for that stage (e.g. ``[poses.backend]`` under ``--poses vio``) refines it; a file naming
    another preset for the same stage is refused. When neither names a matcher preset, the
    matcher is ``default_matcher`` or, when that is None,
    :func:`~vio_depth.pipeline.default_matcher_preset` of the pose source the flags and the
    file choose (``klt`` with the sequence's poses, ``sift`` otherwise); a ``[matcher]`` table
    without ``preset`` refines that matcher. When the file names no ``points``, they are
    :func:`~vio_depth.pipeline.default_points_spec` of the pose source (``vio`` with
    ``--poses vio``, ``sfm`` otherwise).

    Args:
        source: the file's name, prefixed to its errors.

    Raises:
        SettingsError: an unknown preset, table or key, an invalid value, or disagreeing presets.
    """
    data = dict(data or {})
    chosen = dict(presets)
    implied = None
    if "matcher" not in chosen and not chooses_preset(data.get("matcher")):
        implied = default_matcher
        if implied is None:
            others = {k: v for k, v in data.items() if k != "matcher"}
            implied = default_matcher_preset(_apply(others, PipelineSettings.from_presets(**chosen),
                                                    source=source)[0].poses)
    base = PipelineSettings.from_presets(**chosen, **({} if implied is None else {"matcher": implied}))
    try:
        pipeline, run = config_from_dict(data, base)
        named = data.get("points")
        if named is None or (isinstance(named, Mapping) and "source" not in named):
            # the points follow the pose source too (the --points flag comes after; a table without a
            # source refines the default, as for the matcher)
            points = default_points_spec(pipeline.poses)
            if points != pipeline.points.kind.value:
                pipeline = replace(pipeline, points=parse_points_spec(points, seed=pipeline.points.seed))
    except SettingsError as exc:
        hint = ""
        if implied is not None and str(exc).startswith("unknown setting matcher."):
            hint = (f" (a [matcher] table without a preset refines the default matcher, {implied} with these "
                    f"poses; add preset = \"sift\" or another to refine that one)")
        raise SettingsError(f"{source}: {exc}{hint}" if source else f"{exc}{hint}") from None
    names = pipeline.preset_names()
    for family, name in chosen.items():
        if PipelineSettings.from_presets(**{family: name}).preset_names()[family] != names[family]:
            raise SettingsError(f"--{family} {name} and the config file's [{family}] preset "
                                f"{names[family]!r} disagree: drop one of them")
    return pipeline, run


def _apply(data: Mapping[str, Any], pipeline: PipelineSettings | None, run: RunSettings | None = None, *,
           source: str | None = None) -> tuple[PipelineSettings, RunSettings]:
    """:func:`config_from_dict` with the file's name prefixed to its errors."""
    try:
        return config_from_dict(data, pipeline, run)
    except SettingsError as exc:
        raise SettingsError(f"{source}: {exc}" if source else str(exc)) from None
