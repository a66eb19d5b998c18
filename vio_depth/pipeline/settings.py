"""Composable pipeline settings: one settings object per stage, each chosen by preset name.

:class:`PipelineSettings` holds the settings objects of every stage. Each stage family has
named presets (:data:`PRESET_FAMILIES`); a plain dict (a TOML table) selects a preset with
its ``preset`` key and overrides fields by name, e.g.::

    [matcher]
    preset = "sift"
    ratio = 0.75

    [rescaler.ransac]
    inlier_sigmas = 2.5

Every invalid value raises :class:`~vio_core.errors.SettingsError` naming its key path.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

from matchers import MATCHER_PRESETS, KltSettings, LearnedMatcherSettings, MatcherSettings, SiftSettings
from triangulation import TRIANGULATION_PRESETS, ConsistencySettings, TriangulationSettings
from vio_core.errors import SettingsError
from vio_core.settings import Presets, override, to_plain

from ..disparity import DisparitySettings
from ..keyframes import PAIRING_PRESETS, PairingSettings
from ..landmarks import POINTS_WINDOW_BACKEND, LandmarkSettings, WindowBackendSettings
from ..poses import GroundTruthPoseSettings, ImuPoseSettings
from ..rescale import RESCALER_PRESETS, RescalerSettings
from .point_source import PointSourceSpec, parse_points_spec
from ..vio import VioSettings

#: the settings of a pose source: one type per source (:func:`vio_depth.pipeline.build_pose_stage`)
PoseSettings = GroundTruthPoseSettings | ImuPoseSettings | VioSettings

#: The odometry at camera rate (``--poses vio`` since 2026-12-07, before ``vio_realtime``): its
#: window's keyframe updates in a worker process, taken over 4 frames later and refined by iSAM2
#: with at most 600 landmarks; the tracks a keyframe only extends gated against their points
#: instead of triangulated twice; the frames between keyframes bridged again only when the window
#: learnt their keyframe pair better, at the frame after a take-over; KLT tracks and the odometry's
#: own landmarks unless a matcher or points are named (:func:`default_matcher_preset`,
#: :func:`default_points_spec`). docs/benchmarks.md "vio_realtime, 2026-12-06" to "`--poses vio` at
#: camera rate by default, 2026-12-07".
VIO_CAMERA_RATE = VioSettings(backend=WindowBackendSettings(kind="process", lag_frames=4),
                              window=replace(VioSettings().window, solver="isam2", gate_extended_tracks=True,
                                             ba_max_landmarks=600),
                              bridge_every_update=False, defer_bridge_refresh=True)

#: pose-source presets (``--poses``): ``gt`` (the sequence's poses), ``imu`` (gtsam
#: preintegration, the covariance calibrated on EuRoC V1_01), ``imu_real_mav`` (``imu`` with the
#: accelerometer noise x10, for a real MEMS IMU on a vibrating vehicle; docs/benchmarks.md),
#: ``vio`` (visual-inertial odometry from the images and the IMU alone at camera rate:
#: :data:`VIO_CAMERA_RATE`; docs/vio.md), ``vio_offline`` (the same odometry with its window
#: inline, batch-refined, SIFT and two-view points: :class:`VioSettings`' own defaults, ``vio``
#: until 2026-12-07; 10-20 x slower, less drift on short indoor clips, fewer frames with depth)
#: and ``vio_realtime`` (the former name of ``vio``'s settings, kept so that commands and config
#: files written before keep working). They live here, above
#: :mod:`vio_depth.poses` and :mod:`vio_depth.vio`, because they name the settings of both.
POSE_PRESETS: Presets = Presets("pose source", {
    "gt": GroundTruthPoseSettings(),
    "imu": ImuPoseSettings(),
    "imu_real_mav": ImuPoseSettings(accel_noise_scale=10.0),
    "vio": VIO_CAMERA_RATE,
    "vio_offline": VioSettings(),
    "vio_realtime": VIO_CAMERA_RATE,
}, default="gt", descriptions={
    "gt": "the sequence's own metric poses",
    "imu": "gtsam IMU preintegration between keyframes (its covariance enters the points' sigma)",
    "imu_real_mav": "imu with the accelerometer noise x10: a real MEMS IMU on a vibrating vehicle "
                    "(calibrated on EuRoC V1_01)",
    "vio": "visual-inertial odometry from the images and the IMU alone (sequence poses only evaluate), "
           "at camera rate: its window in a worker process, KLT tracks, its own landmarks as points",
    "vio_offline": "vio with its window inline, SIFT and two-view points (vio until 2026-12-07): 10-20 x "
                   "slower; less drift on short indoor clips",
    "vio_realtime": "the same as vio (its name until 2026-12-07)",
})


#: What a tracking front end (``--matcher klt``) changes in the other stages, unless they are set
#: explicitly: ``(stage, field, value)``. Its corners sit on depth edges, so the points where the
#: disparity varies by more than 10 % within 3 px are not fitted; and its flow carries a
#: sub-pixel bias (street frame 1: +0.06 px along the flow at 5-15 m, +0.18 px at 8-12 m,
#: docs/benchmarks.md "Real time and trust, 2026-12-06") that a weak pair -- no keyframe beyond
#: the motion thresholds, 0.4 m of baseline there -- turns into wrong depth (street frame 1:
#: AbsRel 0.066 with 0.009 predicted; room frame 3: 0.046 with 0.019). Without weak pairs the
#: leading frames get their depth from the offline backward pass (street, room, KITTI-tiny:
#: every frame written, none wrong); online they wait for a full pair.
TRACKER_DEFAULTS: tuple[tuple[str, str, Any], ...] = (
    ("rescaler", "max_disparity_spread", 0.1),
    ("pairing", "allow_weak_pairs", False),
)


def with_tracker_defaults(settings: "PipelineSettings", explicit: Mapping[str, Any] | None = None,
                          stages: set[str] | None = None) -> "PipelineSettings":
    """``settings`` with :data:`TRACKER_DEFAULTS` applied when its matcher is a tracker (KLT): to
    the ``stages`` named (None: all), except the fields ``explicit`` sets (a nested dict of stage
    tables, as a config file's: what the user set keeps its value); unchanged for any other matcher."""
    if not isinstance(settings.matcher, KltSettings):
        return settings
    explicit = explicit or {}
    changes: dict[str, dict[str, Any]] = {}
    for stage, name, value in TRACKER_DEFAULTS:
        table = explicit.get(stage)
        if (stages is not None and stage not in stages) or (isinstance(table, Mapping) and name in table):
            continue
        changes.setdefault(stage, {})[name] = value
    return override(settings, changes) if changes else settings


def default_matcher_preset(poses: PoseSettings) -> str:
    """The matcher preset a run uses with the pose source ``poses`` when nothing names one (the
    command line's ``--matcher``, a config file's ``[matcher] preset``).

    ``klt`` with the sequence's own poses (``gt``): it tracks ~500 corners frame to frame instead
    of matching 4 000 SIFT descriptors against two keyframes, runs 2.81 x a bare OpenCV SIFT loop
    on KITTI-tiny's 1242x375 frames where sift runs 0.37 x, and with :data:`TRACKER_DEFAULTS` writes
    no wrong frame and a lower AbsRel than sift on street (0.0194 vs 0.0219), room (0.0121 vs
    0.0127) and KITTI-tiny (0.0434 vs 0.0461) (docs/benchmarks.md "The default matcher, 2026-12-06").
    ``klt`` too with the odometry's window in a worker process (``vio``, :data:`VIO_CAMERA_RATE`): the worker
    answers frames from a window a few frames old, which tracks follow and SIFT's descriptor
    matches against keyframes do not (a lag of 6 cost SIFT 13.8 vs 6.7 mm ATE; with klt, lag 3,
    the generated ASL datasets kept 20 Hz with the default's ATE and AbsRel on 2026-12-06's fast
    machine; lag 4 since 2026-12-07).
    ``sift`` with the other estimated pose sources (``imu``, ``imu_real_mav``, ``vio_offline``): KLT's
    inline odometry drifts twice as far as sift's on street (ATE 12.8 vs 5.9 cm), and klt under ``imu``
    is unmeasured. :class:`PipelineSettings` itself keeps ``sift`` as its field default."""
    if isinstance(poses, GroundTruthPoseSettings):
        return "klt"
    if isinstance(poses, VioSettings) and poses.backend.kind == "process":
        return "klt"
    return "sift"


def default_points_spec(poses: PoseSettings) -> str:
    """The ``--points`` source a run uses with the pose source ``poses`` when nothing names one
    (the command line's ``--points``, a config file's ``points``).

    ``vio`` (the odometry's own landmarks) with the odometry's window in a worker process
    (``vio``, :data:`VIO_CAMERA_RATE`): the camera-rate configuration, and two-view points would match and
    triangulate every frame a second time. On the 752x564 generated ASL loop (SIMULATED, 2-core
    machine, 2026-12-07) that configuration made 22.7 frames/s as fast as possible with its own
    landmarks against 16.9 with two-view points (at 20 Hz 4 against 76 frames dropped), as many
    frames with depth (314 vs 317 of 400) and AbsRel 0.0021 vs 0.0024; offline, where the backward
    pass gives the leading frames two-view points, street 105/130 frames either way, AbsRel 0.0209
    vs 0.0201, room 0.0134 vs 0.0132, none wrong (docs/benchmarks.md "vio_realtime brings its
    landmarks"). ``sfm`` (two-view) with every other pose source: with ``vio_offline`` (sift, inline) the
    odometry's landmarks wrote 2 street frames wrong where two-view wrote none."""
    if isinstance(poses, VioSettings) and poses.backend.kind == "process":
        return "vio"
    return "sfm"


@dataclass(frozen=True)
class PipelineSettings:
    """Everything that shapes a pipeline, one settings object per stage.

    Attributes:
        matcher: features and matching (:data:`matchers.MATCHER_PRESETS`: ``sift``,
            ``disk+lightglue``, ``aliked+lightglue``, ``xfeat+lighterglue``).
        poses: the pose source (:data:`POSE_PRESETS`: ``gt``, ``imu``, ``imu_real_mav``, ``vio``).
        pairing: keyframe and pair selection (``kitti``, ``ddad``, ``indoor``).
        triangulation: per-point checks (:class:`triangulation.TriangulationSettings`).
        rescaler: robust fit, fallbacks and temporal filter (``streaming``, ``per_frame``, ``paper``).
        points: where the metric points come from: ``sfm`` (two-view triangulation with
            keyframes), ``landmarks`` (multi-view landmarks refined over a keyframe window,
            :mod:`vio_depth.landmarks`), ``vio`` (the odometry's own landmarks, with
            ``poses = "vio"``), or a reference source ``lidar:N`` / ``random:N`` sampled from
            ground truth.
        landmarks: the landmark window (``points = "landmarks"``); its pose prior is None by
            default: the preset of the sequence's kind of poses.
        landmarks_backend: where that window's keyframe updates run
            (:class:`~vio_depth.landmarks.WindowBackendSettings`, ``[landmarks_backend]``):
            ``inline`` (the default, reproducible bit for bit) or ``process``, a worker process
            beside the next frames, so that a keyframe's frame does not wait for the window's
            refinement; that frame and the next ``lag_frames`` - 1 are answered from the window
            as it was; ``lag_frames`` 2 by default (:data:`~vio_depth.landmarks.POINTS_WINDOW_BACKEND`).
            Only its ``kind``, ``lag_frames``, ``apply_when_ready``, ``max_pending_keyframes`` and
            ``provisional_landmarks`` apply here (the others concern the odometry's start), and
            ``process`` only with the sequence's poses (``poses = "gt"``). The odometry's own
            window has ``poses.backend``.
        disparity: where the disparity comes from (the sequence's own, files, SIMULATED, a model).
        min_matches: fewer matches than this in a pair -> it is not triangulated.
        consistency: how each pair's stated pose is tested against its matches, and its
            uncertainty inflated where the images show it too small
            (:class:`triangulation.ConsistencySettings`, docs/error_model.md).
    """

    matcher: MatcherSettings = field(default_factory=SiftSettings)
    poses: PoseSettings = field(default_factory=lambda: POSE_PRESETS["gt"])
    pairing: PairingSettings = field(default_factory=lambda: PAIRING_PRESETS["kitti"])
    triangulation: TriangulationSettings = field(default_factory=TriangulationSettings)
    rescaler: RescalerSettings = field(default_factory=RescalerSettings)
    points: PointSourceSpec = field(default_factory=PointSourceSpec)
    landmarks: LandmarkSettings = field(default_factory=LandmarkSettings)
    landmarks_backend: WindowBackendSettings = POINTS_WINDOW_BACKEND
    disparity: DisparitySettings = field(default_factory=DisparitySettings)
    min_matches: int = 20
    consistency: ConsistencySettings = field(default_factory=ConsistencySettings)

    def __post_init__(self):
        if isinstance(self.points, str):
            object.__setattr__(self, "points", parse_points_spec(self.points))
        if isinstance(self.min_matches, bool) or not isinstance(self.min_matches, int) or self.min_matches < 1:
            raise SettingsError(f"min_matches must be a positive integer, got {self.min_matches!r}")

    # ------------------------------------------------------------------ presets
    @classmethod
    def from_presets(cls, *, matcher: str | None = None, poses: str | None = None, pairing: str | None = None,
                     rescaler: str | None = None, triangulation: str | None = None,
                     points: str | None = None, **fields) -> "PipelineSettings":
        """Settings from preset names (None = the family's default) and other fields; a tracking
        matcher (``klt``) brings :data:`TRACKER_DEFAULTS`."""
        s = cls(**fields)
        chosen = {"matcher": matcher, "poses": poses, "pairing": pairing, "rescaler": rescaler,
                  "triangulation": triangulation}
        s = dataclasses.replace(s, **{k: PRESET_FAMILIES[k][v] for k, v in chosen.items() if v is not None})
        if points is not None:
            s = dataclasses.replace(s, points=parse_points_spec(points, seed=s.points.seed))
        return with_tracker_defaults(s) if matcher is not None else s

    @classmethod
    def for_pose_source(cls, poses: str | None = None, *, matcher: str | None = None, points: str | None = None,
                        **presets) -> "PipelineSettings":
        """Settings from preset names as ``vio-depth run`` builds them (without a config file): a
        matcher and points not named follow the pose source (:func:`default_matcher_preset`,
        :func:`default_points_spec`: klt with ``gt``; klt and the odometry's own landmarks with
        ``vio``; sift and two-view pairs otherwise), where :meth:`from_presets` keeps the
        library's field defaults (sift, two-view) whatever the poses. ``presets``: the other
        arguments of :meth:`from_presets`. A robot's :class:`~vio_depth.pipeline.FrameStream` at
        camera rate: ``PipelineSettings.for_pose_source("vio")`` (``from_presets`` would
        give it sift's matching against keyframes a few frames old and two-view points, the
        combination that lost accuracy and did not keep 20 Hz: docs/benchmarks.md)."""
        pose_settings = POSE_PRESETS[poses if poses is not None else POSE_PRESETS.default]
        return cls.from_presets(poses=poses, matcher=matcher or default_matcher_preset(pose_settings),
                                points=points or default_points_spec(pose_settings), **presets)

    def preset_names(self) -> dict[str, str | None]:
        """For each stage family, the preset these settings derive from (by type and extractor)."""
        return {name: family.name_of(getattr(self, name), key=_preset_key) for name, family in PRESET_FAMILIES.items()}

    # ------------------------------------------------------------------ plain dicts / TOML
    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict; each stage table records the ``preset`` it derives from."""
        out = to_plain(self)
        for name, preset in self.preset_names().items():
            if preset is not None:
                out[name] = {"preset": preset, **out[name]}
        out["points"] = {"source": str(self.points), "seed": self.points.seed}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base: "PipelineSettings | None" = None) -> "PipelineSettings":
        """Settings from a nested plain dict (a parsed TOML file) applied on ``base`` (default settings).

        A stage table's ``preset`` key first replaces that stage's settings with the named
        preset; its other keys then override fields. ``points`` is a ``"lidar:16"``-style
        string or a table ``{source = "lidar:16", seed = 0}``.

        Raises:
            SettingsError: an unknown table or key (the valid ones are listed), an unknown
                preset, or an invalid value (its key path is named).
        """
        s = cls() if base is None else base
        if not isinstance(data, Mapping):
            raise SettingsError("settings must be a table")
        valid = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(valid))
        if unknown:
            raise SettingsError(f"unknown settings table(s) {', '.join(unknown)}; valid: {', '.join(valid)}")
        changes: dict[str, Any] = {}
        for name, value in data.items():
            if name == "points":
                changes["points"] = _points_from(value, s.points)
            elif name in PRESET_FAMILIES:
                changes[name] = _stage_from(name, value, getattr(s, name))
            else:
                changes[name] = value
        out = override(s, changes)
        # the tracker's defaults go to every stage when this file switches to it, else to the
        # stages whose table chose a preset here (it replaced them); never over the file's own values
        switched = isinstance(out.matcher, KltSettings) and not isinstance(s.matcher, KltSettings)
        stages = {stage for stage, _, _ in TRACKER_DEFAULTS if switched or chooses_preset(data.get(stage))}
        return with_tracker_defaults(out, data, stages) if stages else out


def _preset_key(settings) -> Any:
    """Presets of one family are told apart by type, and learned matchers by extractor."""
    if isinstance(settings, LearnedMatcherSettings):
        return (type(settings), settings.extractor)
    return type(settings)


def chooses_preset(value) -> bool:
    """Whether a stage's table (or bare name) in a settings dict picks a preset: ``"sift"`` or
    ``{preset = "sift", ...}``."""
    return isinstance(value, str) or (isinstance(value, Mapping) and "preset" in value)


def _stage_from(family: str, value, current):
    if not isinstance(value, Mapping):
        if isinstance(value, str):  # `matcher = "sift"`: a preset name alone
            return PRESET_FAMILIES[family][value]
        raise SettingsError(f"{family}: expected a table or a preset name, got {value!r}")
    table = dict(value)
    base = current
    if "preset" in table:
        base = PRESET_FAMILIES[family][table.pop("preset")]
    return override(base, table, where=family)


def _points_from(value, current: PointSourceSpec) -> PointSourceSpec:
    if isinstance(value, str):
        return parse_points_spec(value, seed=current.seed)
    if not isinstance(value, Mapping):
        raise SettingsError(f"points: expected 'sfm', 'lidar:N', 'random:N' or a table, got {value!r}")
    table = dict(value)
    unknown = sorted(set(table) - {"source", "seed"})
    if unknown:
        raise SettingsError(f"unknown setting(s) points.{', points.'.join(unknown)}; valid: seed, source")
    seed = table.get("seed", current.seed)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise SettingsError(f"points.seed: expected an integer, got {seed!r}")
    return parse_points_spec(table.get("source", str(current)), seed=seed)


#: Every stage family with named presets (``vio-depth presets`` lists them).
PRESET_FAMILIES: dict[str, Presets] = {
    "matcher": MATCHER_PRESETS,
    "poses": POSE_PRESETS,
    "pairing": PAIRING_PRESETS,
    "triangulation": TRIANGULATION_PRESETS,
    "rescaler": RESCALER_PRESETS,
}
