"""Settings of the landmark estimator: pose-prior uncertainty per dataset kind and the window.

Pose priors (:class:`PosePriorSettings`) state how far a sequence's keyframe poses may be
from the truth, as 1-sigma values:

* ``absolute_*``: each keyframe's pose in the world (the gauge, and a bound on drift);
* ``relative_*``: the motion between consecutive keyframes (odometry-like; much tighter
  than the absolute error for KinectFusion, mocap and INS, whose errors are correlated
  in time). The relative translation sigma is ``relative_translation_m +
  relative_translation_fraction * |t|``.

The images refine the poses within these bounds; the metric scale is held by the priors
(or by IMU factors, :class:`~vio_depth.landmarks.window.MotionFactorSource`), never by the
images. Presets (:data:`POSE_PRIOR_PRESETS`) name dataset kinds; their numbers are
stated guesses checked where we have data (docs/benchmarks.md, "Landmarks").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from triangulation.multiview import MultiviewSettings
from vio_core.errors import SettingsError, UnknownNameError
from vio_core.settings import Presets


@dataclass(frozen=True)
class PosePriorSettings:
    """1-sigma uncertainty of keyframe poses given by the sequence (see the module docstring).

    Attributes:
        absolute_rotation_deg / absolute_translation_m: of each pose in the world; the
            first keyframe always gets this prior (it fixes the gauge).
        relative_rotation_deg / relative_translation_m / relative_translation_fraction:
            of the motion between consecutive keyframes.
        relative_translation_axes: multipliers of the relative translation sigma along the
            later keyframe's camera axes (x right, y down, z optical axis). KinectFusion
            tracks depth images by ICP, which pins motion along the viewing direction much
            better than sliding along the (often planar) surfaces: (4, 4, 0.4).
        absolute_on_every_keyframe: False when only the first keyframe is anchored and
            motion factors (IMU) carry the rest; the relative priors are then not added
            either (the motion factor source replaces them).
    """

    absolute_rotation_deg: float = 1.0
    absolute_translation_m: float = 0.05
    relative_rotation_deg: float = 0.2
    relative_translation_m: float = 0.003
    relative_translation_fraction: float = 0.02
    relative_translation_axes: tuple[float, float, float] = (1.0, 1.0, 1.0)
    absolute_on_every_keyframe: bool = True

    def __post_init__(self):
        values = (self.absolute_rotation_deg, self.absolute_translation_m, self.relative_rotation_deg,
                  self.relative_translation_m)
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise SettingsError("pose prior sigmas must be finite and > 0")
        if not self.relative_translation_fraction >= 0:
            raise SettingsError("relative_translation_fraction must be >= 0")
        axes = tuple(float(a) for a in self.relative_translation_axes)
        if len(axes) != 3 or not all(math.isfinite(a) and a > 0 for a in axes):
            raise SettingsError("relative_translation_axes must be three finite values > 0")
        object.__setattr__(self, "relative_translation_axes", axes)

    def relative_translation_sigma(self, translation_m: float) -> float:
        """1-sigma (metres) of a keyframe-to-keyframe translation of ``translation_m`` metres
        (before the per-axis multipliers)."""
        return self.relative_translation_m + self.relative_translation_fraction * abs(translation_m)

    def relative_sigmas(self, translation_m: float):
        """(6,) 1-sigma of a relative pose: rotation (rad) x 3, then translation (m) per axis."""
        t = self.relative_translation_sigma(translation_m)
        return np.array([math.radians(self.relative_rotation_deg)] * 3 + [t * a for a in self.relative_translation_axes])


#: Pose-prior presets by dataset kind. "exact": rendered sequences (sample_sequences);
#: "mocap": motion capture (EuRoC Vicon, TUM); "kinectfusion": 7-Scenes; "ins": KITTI OXTS;
#: "imu": only the first keyframe is anchored, a MotionFactorSource must add the rest.
POSE_PRIOR_PRESETS: Presets = Presets("pose prior preset", {
    # rendered: exact up to float noise
    "exact": PosePriorSettings(0.01, 0.001, 0.005, 0.0002, 0.001),
    # Vicon/OptiTrack marker poses mapped to the camera: not measured here (a stated guess)
    "mocap": PosePriorSettings(0.1, 0.005, 0.05, 0.002, 0.01),
    # 7-Scenes: translations jitter by ~1 cm around the (drift-free) model: PnP of the colour
    # images on the Kinect depth disagrees with them by 5-37 mm over 6 frames, at any gap,
    # so there is no useful relative (odometry-like) translation prior; rotations are kept
    # tight because freeing them makes the refined geometry agree *worse* with the Kinect
    # depth (docs/benchmarks.md, "Landmarks")
    "kinectfusion": PosePriorSettings(0.05, 0.01, 0.05, 1.0, 0.0),
    # KITTI OXTS (RTK GPS/INS): absolute metres, relative cm
    "ins": PosePriorSettings(0.1, 0.3, 0.05, 0.02, 0.01),
    "imu": PosePriorSettings(0.01, 0.001, 1.0, 0.1, 0.0, absolute_on_every_keyframe=False),
}, default="exact", descriptions={
    "exact": "rendered sequences (the bundled samples)",
    "mocap": "motion capture (EuRoC Vicon, TUM): a stated guess",
    "kinectfusion": "7-Scenes KinectFusion poses: ~1 cm jitter, tight rotations",
    "ins": "KITTI OXTS RTK GPS/INS: absolute metres, relative cm",
    "imu": "first keyframe anchored only; IMU factors carry the rest",
})


def pose_prior_preset(name: str, **overrides) -> PosePriorSettings:
    """Preset ``name`` of :data:`POSE_PRIOR_PRESETS` with optional field overrides.

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    return replace(POSE_PRIOR_PRESETS[name], **overrides)


#: how a keyframe refines the landmark window (:attr:`LandmarkSettings.solver`)
LANDMARK_SOLVERS = ("batch", "isam2")


@dataclass(frozen=True)
class LandmarkSettings:
    """Everything that shapes the landmark estimator (one default for indoors and outdoors).

    Attributes:
        pose_prior: :class:`PosePriorSettings` of the sequence's poses, or None (the
            default): the preset of the sequence's kind of poses (``Sequence.pose_kind``:
            ``exact`` for rendered samples, ``ins`` for KITTI, ``kinectfusion`` for
            7-Scenes, ``mocap`` for TUM, EuRoC and other native sequences).
        multiview: track triangulation and qualification (:class:`MultiviewSettings`):
            pixel sigma, residual gate in sigmas, ``max_relative_sigma``.
        window_keyframes: keyframes kept in the window; the oldest is marginalised
            beyond it (bounds memory and time). 8 (16 before 2026-12-06): with the
            sequence's poses it cut the window's CPU by 10-25 % for AbsRel within 1 % on
            street, room and KITTI-tiny (street SIFT 0.0194 -> 0.0196; 6 gave 0.0205);
            docs/benchmarks.md "The landmark window at 1.5 x". The odometry's window keeps 16.
        match_keyframes: newest keyframes every frame is matched with (SIFT matching is the
            window's largest per-frame cost on feature-rich frames: 3 -> 2 cut it by a third
            at the same AbsRel on street and room, docs/benchmarks.md).
        refresh_keyframes: after a refinement, the tracks seen by the newest this many
            keyframes are triangulated again at the refined poses (besides the tracks the new
            keyframe changed); the others keep their last triangulation, made at the previous
            refinement's poses. 1: the new keyframe's tracks only (the second triangulation was
            a third of a keyframe's cost, and with the sequence's poses as priors a refinement
            moves the older keyframes little); the odometry's window, whose poses come from
            the IMU, refreshes every keyframe it matches with.
        min_track_length: fewest keyframe observations of a landmark in the graph.
        huber_sigmas: Huber threshold of the projection factors, in pixel sigmas.
        ba_relative_sigma_factor: tracks enter the graph when VALID, or UNCERTAIN with a
            predicted relative depth sigma up to this factor times ``max_relative_sigma``
            before refinement (the poses' prior uncertainty inflates it; the refinement is
            what shrinks it). Only VALID tracks after refinement are returned as points.
        keyframe_relative_sigma: a frame becomes a keyframe when the median predicted
            relative depth sigma of its two-view matches with the newest keyframe falls
            below this (enough new parallax -- measured against pixel and pose
            uncertainty, so the same value serves any scene scale). Each keyframe costs a
            window refinement (~100 ms on 1242x375 street frames, two-thirds of the window's
            cost), so a looser bound that makes most frames keyframes buys little accuracy:
            0.25 -> 0.15 took 66 -> 42 (SIFT) and 109 -> 59 (KLT) keyframes on the 130 street
            frames for AbsRel 0.0194 -> 0.0199 and 0.0186 -> 0.0187; 0.12 (with
            ``match_keyframes`` 2) keeps street at 0.0194 / 0.0191; 0.10 was cheaper still but
            worse on KITTI-tiny's real frames (docs/benchmarks.md) ...
        keyframe_min_tracked_fraction: ... or when fewer than this fraction of the
            newest keyframe's tracked landmarks are found in the frame (the view changed).
        max_keyframe_gap: ... or when this many frames passed since the newest keyframe.
        ba_max_landmarks: most landmarks in the graph (the longest tracks, then the most
            certain); every track is triangulated at the refined poses afterwards.
        lm_max_iterations: Levenberg-Marquardt iterations per keyframe.
        lm_min_error_decrease: Levenberg-Marquardt stops after an iteration that lowered the
            graph error (half the sum of squared whitened residuals) by less than this
            (gtsam's ``absoluteErrorTol``); e.g. 0.5: a change well inside one sigma of the
            estimate is not worth another full linear solve of the window.
        restart_from_priors: with pose priors on every keyframe, each refinement starts
            from the priors instead of the previous estimate (robust to a window that went
            astray; costs a few more iterations). The batch solver only: iSAM2 keeps its
            linearisation point.
        query_max_iterations: Gauss-Newton iterations of a frame's pose refinement.
        min_query_points: fewer associated landmarks than this -> the frame's pose is
            not refined (its prior is used) and it is reported.
        solver: how a keyframe refines the window (:data:`LANDMARK_SOLVERS`): ``"batch"``
            re-solves the whole window from scratch by Levenberg-Marquardt, then
            ``gtsam.Marginals`` (:mod:`.graph`); ``"isam2"`` (the default since 2026-12-06)
            updates gtsam's iSAM2 with the keyframe's changes only (:mod:`.isam`;
            docs/benchmarks.md "Incremental window (iSAM2)"): AbsRel within 1 % with the
            sequence's or IMU poses for 8-20 % less window CPU ("The landmark window at
            1.5 x"). The odometry's window keeps ``"batch"`` (iSAM2 drifted more on the
            street drive under ``--poses vio``).
        gate_extended_tracks: before a refinement, a track that only gained the new
            keyframe's observation keeps its point and that observation is judged against it
            (:func:`~.incremental.gate_extensions`) instead of the track being triangulated
            again (after the refinement every track the new keyframe sees is triangulated
            again either way). With KLT tracks nearly every track is such a one: this saves a
            fifth of a keyframe update of the odometry's window (``--poses vio``).
    """

    pose_prior: PosePriorSettings | None = None
    multiview: MultiviewSettings = field(default_factory=MultiviewSettings)
    window_keyframes: int = 8
    match_keyframes: int = 2
    refresh_keyframes: int = 1
    min_track_length: int = 2
    huber_sigmas: float = 2.0
    ba_relative_sigma_factor: float = 3.0
    keyframe_relative_sigma: float = 0.12
    keyframe_min_tracked_fraction: float = 0.5
    max_keyframe_gap: int = 30
    ba_max_landmarks: int = 800
    lm_max_iterations: int = 15
    lm_min_error_decrease: float = 0.5
    restart_from_priors: bool = True
    query_max_iterations: int = 5
    min_query_points: int = 12
    solver: str = "isam2"
    gate_extended_tracks: bool = False

    def __post_init__(self):
        if self.solver not in LANDMARK_SOLVERS:
            raise UnknownNameError("landmark solver", self.solver, LANDMARK_SOLVERS)
        if self.window_keyframes < 2 or self.match_keyframes < 1 or self.refresh_keyframes < 1:
            raise SettingsError("window_keyframes must be >= 2, match_keyframes and refresh_keyframes >= 1")
        if self.min_track_length < 2:
            raise SettingsError("min_track_length must be >= 2")
        if not (self.huber_sigmas > 0 and self.keyframe_relative_sigma > 0):
            raise SettingsError("huber_sigmas and keyframe_relative_sigma must be > 0")
        if not 0 <= self.keyframe_min_tracked_fraction <= 1:
            raise SettingsError("keyframe_min_tracked_fraction must be in [0, 1]")
        if self.ba_max_landmarks < 1:
            raise SettingsError("ba_max_landmarks must be >= 1")
        if self.max_keyframe_gap < 1 or self.lm_max_iterations < 1 or self.query_max_iterations < 0:
            raise SettingsError("max_keyframe_gap and lm_max_iterations must be >= 1, query_max_iterations >= 0")
        if not self.lm_min_error_decrease >= 0:
            raise SettingsError("lm_min_error_decrease must be >= 0")
        if self.min_query_points < 3:
            raise SettingsError("min_query_points must be >= 3")

    def resolved(self, pose_kind: str) -> "LandmarkSettings":
        """These settings with the pose prior of ``pose_kind`` (a :data:`POSE_PRIOR_PRESETS`
        name) when ``pose_prior`` is None (the default), else unchanged."""
        return self if self.pose_prior is not None else replace(self, pose_prior=POSE_PRIOR_PRESETS[pose_kind])

    @classmethod
    def for_poses(cls, kind: str, **overrides) -> "LandmarkSettings":
        """Defaults with the pose-prior preset ``kind`` (see :data:`POSE_PRIOR_PRESETS`)."""
        return cls(pose_prior=pose_prior_preset(kind), **overrides)


#: where the window's keyframe updates run (:class:`WindowBackendSettings`)
WINDOW_BACKENDS = ("inline", "process")


@dataclass(frozen=True)
class WindowBackendSettings:
    """Where the landmark window's keyframe updates run (:mod:`.backend`).

    Attributes:
        kind: ``"inline"`` (the default): in the caller, at the keyframe -- the frame that
            becomes a keyframe waits for the window's refinement, and runs are reproducible
            bit for bit. ``"process"``: in a worker process beside the next frames (the
            peers' tracking/mapping split: VINS-Mono, ORB-SLAM): the keyframe's frame is
            answered at once from the window as it was, the following frames are tracked
            against it too, and the refined window is taken over ``lag_frames`` frames later
            (waiting for it then if it is not ready).
        lag_frames: frames after a keyframe at which its update is taken over (>= 1). The
            default 6 lets a ~170 ms update finish beside 20 Hz KLT tracking on two cores
            (docs/benchmarks.md "The landmark window in a worker process"); SIFT's frames,
            matched against keyframe descriptors, lose accuracy with a long lag (2: ASL sample
            ATE 7.1 vs 6.7 mm; 6: 13.8 mm).
        start_lag_frames: frames after an initialisation (for a dynamic one run in the worker:
            after the frame that submitted it, at least one after its take-over) at which the
            window built from its keyframes in the worker is taken over (waiting for it then if
            it is not ready);
            the frames meanwhile are not posed (``initialising``). 0: the initialisation's
            frame waits for it, as inline. The default 20 (one second at 20 Hz) covers the
            worker's start (its interpreter imports the pipeline: 1-3 s on two cores, while
            the first frames are read) and a six-keyframe start (~1.2 s; docs/benchmarks.md).
        init_lag_frames: frames after a VIO's dynamic initialisation attempt (the visual
            reconstruction and the IMU alignment, ~0.4 s on the ASL sample), run in the worker,
            at which its outcome is taken over (waiting for it then if it is not ready); the
            frames meanwhile keep initialising (and collecting candidates). 0: the attempt's
            frame waits for it (the synchronous start's outcome). The default 10 (0.5 s at
            20 Hz) covers the attempt beside the tracking on two cores.
        apply_when_ready: take an update (a start's and an initialisation attempt's too) over as
            soon as it is ready, at the first frame after it (still at the latest ``lag_frames`` /
            ``start_lag_frames`` / ``init_lag_frames`` after it): lower latency and more
            keyframes on a fast machine, but the result depends on timing -- off for
            reproducible runs and tests.
        catch_up_keyframes: a VIO's dynamic start taken over from the worker: candidate
            keyframes the initialisation collected after the attempt's newest keyframe (while
            the attempt ran), up to this many, spread evenly in time, join the start's window
            after its keyframes (posed by the IMU). 0: the first keyframe tracked after the
            start is matched with the attempt's newest across both lags (~20 frames).
        max_pending_keyframes: keyframes submitted to the worker and not taken over yet, at
            most. 1: no new keyframe is chosen while one is pending (a keyframe at most every
            ``lag_frames`` frames: at driving speed the tracks leave the view in between and
            the window thins out). More: the policy goes on against the newest pending keyframe
            (its matches, its pose as estimated when it was submitted) and queues the next one
            in the worker, which inserts them in order; each is taken over ``lag_frames``
            after its own submission. A full queue chooses no keyframe.
    """

    kind: str = "inline"
    lag_frames: int = 6
    apply_when_ready: bool = False
    start_lag_frames: int = 20
    init_lag_frames: int = 10
    catch_up_keyframes: int = 2
    max_pending_keyframes: int = 1
    provisional_landmarks: bool = False

    def __post_init__(self):
        if self.kind not in WINDOW_BACKENDS:
            raise UnknownNameError("window backend", self.kind, WINDOW_BACKENDS)
        if not (isinstance(self.lag_frames, int) and self.lag_frames >= 1):
            raise SettingsError("window backend lag_frames must be an integer >= 1")
        if not (isinstance(self.start_lag_frames, int) and self.start_lag_frames >= 0):
            raise SettingsError("window backend start_lag_frames must be an integer >= 0")
        if not (isinstance(self.init_lag_frames, int) and self.init_lag_frames >= 0):
            raise SettingsError("window backend init_lag_frames must be an integer >= 0")
        if not (isinstance(self.catch_up_keyframes, int) and self.catch_up_keyframes >= 0):
            raise SettingsError("window backend catch_up_keyframes must be an integer >= 0")
        if not (isinstance(self.max_pending_keyframes, int) and self.max_pending_keyframes >= 1):
            raise SettingsError("window backend max_pending_keyframes must be an integer >= 1")
        if not isinstance(self.provisional_landmarks, bool):
            raise SettingsError("window backend provisional_landmarks must be true or false")
        if self.provisional_landmarks and self.max_pending_keyframes > 1:
            raise SettingsError("window backend: provisional_landmarks with max_pending_keyframes > 1 chains "
                                "unrefined keyframes (the street sample's scale drifted 10-17 %); use one of them")


#: where the points window's updates run by default (``PipelineSettings.landmarks_backend``):
#: inline; with ``kind = "process"``, taken over 2 frames later (3 left the street sample 60
#: points a frame instead of 72 and AbsRel 0.0209 instead of 0.0198; docs/benchmarks.md "The
#: points window in a worker process")
POINTS_WINDOW_BACKEND = WindowBackendSettings(lag_frames=2)
