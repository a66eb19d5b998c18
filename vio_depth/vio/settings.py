"""Settings of the visual-inertial odometry pose source (``--poses vio``), next to its code.

The preset ``vio`` of :data:`vio_depth.pipeline.POSE_PRESETS` is ``VioSettings()``;
:func:`vio_depth.pipeline.build_pose_stage` builds the :class:`~vio_depth.vio.VioPoseSource`
for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from triangulation.multiview import MultiviewSettings
from vio_core.errors import SettingsError
from vio_core.settings import require_positive

from ..landmarks.settings import LandmarkSettings, PosePriorSettings, WindowBackendSettings
from ..poses import ImuPoseSettings, StaticInitSettings


@dataclass(frozen=True)
class VioInitSettings:
    """How the estimator starts from nothing (docs/vio.md, "Initialisation").

    Static start (tried first): the IMU was still for ``static.min_still_s`` seconds up to
    the frame, and so were the images (median keypoint motion below ``still_flow_px``).

    Dynamic start (VINS-Mono's idea): at least ``min_keyframes`` frames, each with at least
    ``min_parallax_deg`` of median keypoint motion (rotation removed) after the previous
    one, spanning at least ``min_duration_s``, are reconstructed up to scale (essential
    matrix, PnP, bundle adjustment) and aligned with the preintegrated IMU for the
    gyroscope bias, the scale, gravity and the velocities. It is tried again on every new
    keyframe while it is refused (beyond ``max_duration_s`` the oldest keyframe is dropped,
    beyond ``max_keyframes`` the one closest in time to its neighbours; a failed
    reconstruction drops the oldest):

    Attributes:
        static: still-interval detection (:class:`~vio_depth.poses.StaticInitSettings`).
        still_flow_px: largest median keypoint motion of a still camera, pixels.
        lookback_s: IMU seconds before the frame searched for the still interval.
        dynamic: allow the dynamic start.
        min_keyframes / max_keyframes: keyframes of the dynamic start.
        min_parallax_deg: median keypoint motion between two of them, degrees of view
            (resolution independent: 1.4 deg is 10 px at a focal length of 420 px).
        min_duration_s / max_duration_s: time they span.
        min_landmarks: fewest reconstructed points (``too few tracks``).
        max_residual_px: largest median reprojection residual of the reconstruction.
        max_gravity_error: largest ``| |g_est| - |g| |`` before the magnitude is imposed, m/s^2.
        max_scale_sigma: largest relative 1-sigma of the scale (``too little excitation``).
        min_acceleration: smallest RMS of the IMU's acceleration change over the keyframes, m/s^2
            (``too little excitation``: uniform motion leaves the scale unobservable).
        max_gyro_bias: largest plausible gyroscope bias, rad/s.
        max_scale_change: largest relative change of the scale between the alignment and the
            visual-inertial refinement of the same keyframes.
    """

    static: StaticInitSettings = field(default_factory=StaticInitSettings)
    still_flow_px: float = 1.0
    lookback_s: float = 3.0
    dynamic: bool = True
    min_keyframes: int = 6
    max_keyframes: int = 10
    min_parallax_deg: float = 1.4
    min_duration_s: float = 0.6
    max_duration_s: float = 8.0
    min_landmarks: int = 40
    max_residual_px: float = 2.0
    max_gravity_error: float = 1.0
    max_scale_sigma: float = 0.1
    min_acceleration: float = 0.15
    max_gyro_bias: float = 0.2
    max_scale_change: float = 0.15

    def __post_init__(self):
        require_positive(self, "still_flow_px", "lookback_s", "min_parallax_deg", "min_duration_s", "max_duration_s",
                         "max_residual_px", "max_gravity_error", "max_scale_sigma", "max_gyro_bias", "max_scale_change")
        if not 3 <= self.min_keyframes <= self.max_keyframes:
            raise SettingsError(f"VioInitSettings: need 3 <= min_keyframes <= max_keyframes, got "
                                f"{self.min_keyframes}, {self.max_keyframes}")
        if self.min_landmarks < 8:
            raise SettingsError(f"VioInitSettings.min_landmarks must be >= 8, got {self.min_landmarks}")
        if not self.min_acceleration >= 0:
            raise SettingsError(f"VioInitSettings.min_acceleration must be >= 0, got {self.min_acceleration}")
        if self.max_duration_s <= self.min_duration_s:
            raise SettingsError("VioInitSettings: max_duration_s must exceed min_duration_s")


@dataclass(frozen=True)
class RestSettings:
    """The zero-velocity test of the odometry (:mod:`vio_depth.vio.rest`, in the style of
    OpenVINS's ``UpdaterZeroVelocity``) and the uncertainty of a resting frame.

    A tracked frame rests when all of these pass:

    * the odometry: the newest keyframe's estimated speed is at most ``max_speed_m_s``
      (OpenVINS's ``zupt_max_velocity``): a camera the odometry tracks in uniform motion is not
      at rest, however little its keypoints move from one frame to the next;

    * IMU: the samples since the previous frame (at least ``min_imu_s`` of them), averaged
      over blocks of ``imu_block_s`` (vibration averages out), fit the zero-velocity
      hypothesis, gyroscope = bias and accelerometer = gravity in the body frame + bias (the
      newest keyframe's estimates), within the IMU's white-noise densities
      times ``imu_noise_multiplier`` and the estimates' own uncertainty (``tilt_sigma_rad``,
      ``accel_bias_sigma``, ``gyro_bias_sigma``): chi-square below its ``chi2_probability``
      quantile for the residual's dimension;
    * images, frame to frame: the median keypoint motion since the previous frame, rotation
      removed with the gyroscope, is below ``max_disparity_px``, over at least
      ``min_features`` matches;
    * images, since the rest began: the distance the camera moved since the frame whose pose
      the rest holds (the anchor), over the scene's depth, estimated from the keypoint motion
      left once the gyroscope's rotation is removed (:func:`~vio_depth.vio.rest.anchor_motion`),
      is not more than ``anchor_motion_sigmas`` sigma beyond ``max_anchor_motion``. The sigma
      comes from the keypoint noise and the uncertainty of the gyroscope's rotation since the
      anchor (:func:`~vio_depth.vio.rest.gyro_rotation_sigma`: its bias, an average over
      ``gyro_bias_window_s``, and its noise, both from the scatter the gyroscope shows at
      rest): a sideways motion is almost the flow of a rotation, so it counts only as far as
      the rotation is sure, while a motion along the view counts whatever the rotation. The
      IMU cannot tell rest from uniform motion and the frame-to-frame motion of a creeping
      camera hides in the keypoint noise; its motion since the anchor grows until this test fails.

    A resting frame keeps the anchor's position (its orientation follows the gyroscope) and
    its covariance grows with the time ``dt`` since the anchor: variance
    ``translation_random_walk ** 2 * dt`` and ``rotation_random_walk ** 2 * dt`` on top of
    the anchor's (a motion too slow to detect still adds up).

    Attributes:
        max_speed_m_s: the newest keyframe's estimated speed, m/s, above which no frame rests.
        imu_noise_multiplier: factor on the IMU noise variances in the test (OpenVINS
            ``zupt_noise_multiplier``): a resting platform vibrates. On the EuRoC V1_01 still
            slice (rotors running) the 0.25 s accelerometer standard deviation is 0.1-1.3 m/s^2
            against the datasheet's 0.03 per sample; 400 lets that rest pass while a hand-held
            camera's rotation (0.1 rad/s and more) still fails.
        chi2_probability: quantile of the chi-square distribution used as the IMU threshold.
        tilt_sigma_rad / accel_bias_sigma / gyro_bias_sigma: 1-sigma of the newest keyframe's
            roll/pitch (rad), accelerometer bias (m/s^2) and gyroscope bias (rad/s) in the test.
        min_imu_s: shortest IMU interval tested, seconds (earlier samples are added).
        imu_block_s: seconds of IMU samples averaged into one residual of the test.
        max_disparity_px: largest median keypoint motion since the previous frame, pixels.
        max_anchor_motion: distance moved since the anchor over the scene's depth held as rest
            (0.001: 5 mm at 5 m) when the images are sure of it.
        anchor_motion_sigmas: how many sigma beyond ``max_anchor_motion`` end the rest. On the
            real EuRoC V1_01 still slice (rotors running) the gyroscope scatters 6-7 mrad/s over
            0.05 s blocks (the datasheet: 0.8), its static-start bias is off by 1-2 mrad/s, and
            the sideways motion the gyroscope's rotation leaves (0.5 % of the depth after 3.6 s)
            stays within its sigma; a camera creeping sideways in the simulated scenes (whose
            gyroscope scatters as its datasheet says) is caught after 0.1-0.15 %. On that slice the
            motion stays within 0.05 sigma of 0.1 %; 1 leaves the simulated creep tests their margin.
        gyro_bias_window_s: seconds of gyroscope samples the bias is taken to average (a static
            start's still second): its error is the scatter over this window.
        min_features: fewest matches for either image test.
        translation_random_walk: m/sqrt(s), growth of a resting frame's position sigma.
        rotation_random_walk: rad/sqrt(s), growth of its orientation sigma.
    """

    max_speed_m_s: float = 0.05
    imu_noise_multiplier: float = 400.0
    chi2_probability: float = 0.99
    tilt_sigma_rad: float = 0.01
    accel_bias_sigma: float = 0.05
    gyro_bias_sigma: float = 0.002
    min_imu_s: float = 0.1
    imu_block_s: float = 0.05
    max_disparity_px: float = 1.5
    max_anchor_motion: float = 0.001
    anchor_motion_sigmas: float = 1.0
    gyro_bias_window_s: float = 1.0
    min_features: int = 20
    translation_random_walk: float = 0.005
    rotation_random_walk: float = 0.001

    def __post_init__(self):
        require_positive(self, "max_speed_m_s", "imu_noise_multiplier", "tilt_sigma_rad", "accel_bias_sigma",
                         "gyro_bias_sigma", "min_imu_s", "imu_block_s", "max_disparity_px", "max_anchor_motion",
                         "anchor_motion_sigmas", "gyro_bias_window_s", "translation_random_walk",
                         "rotation_random_walk")
        if not 0.0 < self.chi2_probability < 1.0:
            raise SettingsError(f"RestSettings.chi2_probability must be in (0, 1), got {self.chi2_probability}")
        if self.min_features < 5:
            raise SettingsError(f"RestSettings.min_features must be >= 5, got {self.min_features}")


def _vio_window() -> LandmarkSettings:
    """The landmark window of the VIO: only the first keyframe is anchored (the IMU factors
    carry the rest), so its absolute prior is loose; the estimator adds its own gauge prior."""
    prior = PosePriorSettings(absolute_rotation_deg=10.0, absolute_translation_m=1.0, relative_rotation_deg=1.0,
                              relative_translation_m=0.1, relative_translation_fraction=0.0,
                              absolute_on_every_keyframe=False)
    return LandmarkSettings(pose_prior=prior, multiview=MultiviewSettings(pixel_sigma_px=1.0), window_keyframes=16,
                            match_keyframes=3, refresh_keyframes=3, keyframe_relative_sigma=0.1, max_keyframe_gap=10, restart_from_priors=False,
                            solver="batch")


@dataclass(frozen=True)
class VioSettings:
    """Settings of the visual-inertial odometry pose source (:mod:`vio_depth.vio`).

    Attributes:
        window: the landmark window (tracks, projection factors, keyframe policy, window
            length); its pose prior only anchors the first keyframe loosely.
        imu: IMU noise scales, sample gaps and bias prior sigmas (:class:`ImuPoseSettings`;
            the fields about sequence poses are not used).
        init: :class:`VioInitSettings`.
        velocity_sigma: 1-sigma of a static start's zero velocity, m/s.
        gauge_sigma_m / gauge_yaw_sigma_rad: prior of the first keyframe's position and yaw
            (unobservable: they fix the world frame).
        tilt_sigma_rad: prior 1-sigma of the first keyframe's roll and pitch (beyond the
            initialisation's own estimate).
        max_scale_sigma: a frame's pose is trusted only while the window knows the metric scale
            to this relative 1-sigma (the distance between its oldest and newest keyframe,
            from the smoother's covariance); before, e.g. just after a start with little
            excitation, the frame has no pose (status ``converging``) ...
        min_span_sigma_m: ... unless that 1-sigma is below this many metres (a still or slow
            camera after a static start: its short span is known well).
        max_speed_m_s: a faster estimated velocity means the estimate diverged.
        max_accel_bias / max_gyro_bias: larger estimated biases mean it diverged.
        max_imu_only_s: longest time without enough landmarks before tracking is lost.
        min_tracked_landmarks: fewer landmarks in a keyframe counts as "without landmarks".
        predict_velocity_sigma / predict_gyro_sigma: 1-sigma of the newest keyframe's velocity
            (m/s) and gyroscope bias (rad/s) in the covariance of a frame's IMU prediction
            (its pose prior against the landmarks, and its pose when they are too few).
        epipolar_threshold_px: RANSAC distance of the epipolar gate on every pair's matches
            (:mod:`vio_depth.vio.matching`), ideal pixels.
        history_frames: frames whose poses are remembered (for relative poses with old
            keyframes and the offline backward pass); bounds memory.
        rest: the zero-velocity test (:class:`RestSettings`). A resting frame keeps the
            position of the frame before the rest, its orientation follows the gyroscope, and
            the window is not updated, so a resting camera neither drifts on the IMU alone
            nor loses tracking for lack of parallax.
        backend: where the window's keyframe updates run
            (:class:`~vio_depth.landmarks.WindowBackendSettings`): ``inline`` (default,
            reproducible) or ``process`` (a worker process beside the tracking, for camera-rate
            streaming; docs/vio.md).
        bridge_every_update: the frames between two keyframes are posed again by the IMU
            between them (a bridge, :mod:`vio_depth.vio.bridge`) after every window update
            while both keyframes are in it (True, the default), or only when the pair is new
            and once the window knows the pair's relative pose 20 % better than when it was
            last bridged (False: ``--poses vio``; meanwhile they follow the later keyframe as
            it moves). The eager refresh re-poses some 60 frames of a 16-keyframe window at
            every update: 33 ms a keyframe on the 752x564 ASL loop, 14 ms without it
            (docs/benchmarks.md "vio_realtime's worker").
        defer_bridge_refresh: a keyframe update taken over from the worker process re-poses the
            bridged frames (``bridge_every_update``) at the next frame that takes none over, or
            when the odometry's poses of other frames are read, not in the take-over frame (True:
            ``--poses vio``; the take-over frame is the slowest of a camera-rate stream, and the
            bridged frames are past ones: docs/benchmarks.md "Bridges after the take-over").
    """

    window: LandmarkSettings = field(default_factory=_vio_window)
    imu: ImuPoseSettings = field(default_factory=ImuPoseSettings)
    init: VioInitSettings = field(default_factory=VioInitSettings)
    velocity_sigma: float = 0.01
    max_scale_sigma: float = 0.03
    min_span_sigma_m: float = 0.01
    gauge_sigma_m: float = 1e-3
    gauge_yaw_sigma_rad: float = 1e-3
    tilt_sigma_rad: float = 0.02
    max_speed_m_s: float = 60.0
    max_accel_bias: float = 1.0
    max_gyro_bias: float = 0.2
    max_imu_only_s: float = 2.0
    min_tracked_landmarks: int = 10
    epipolar_threshold_px: float = 1.0
    predict_velocity_sigma: float = 0.05
    predict_gyro_sigma: float = 0.002
    history_frames: int = 20000
    rest: RestSettings = field(default_factory=RestSettings)
    backend: WindowBackendSettings = field(default_factory=WindowBackendSettings)
    bridge_every_update: bool = True
    defer_bridge_refresh: bool = False

    def __post_init__(self):
        require_positive(self, "velocity_sigma", "max_scale_sigma", "min_span_sigma_m", "gauge_sigma_m",
                         "gauge_yaw_sigma_rad", "tilt_sigma_rad", "max_speed_m_s", "max_accel_bias", "max_gyro_bias",
                         "max_imu_only_s", "epipolar_threshold_px", "predict_velocity_sigma", "predict_gyro_sigma")
        if self.window.pose_prior.absolute_on_every_keyframe:
            raise SettingsError("VioSettings.window.pose_prior.absolute_on_every_keyframe must be false: "
                                "the IMU factors, not sequence poses, carry the window")
        if self.init.max_keyframes > self.window.window_keyframes:
            raise SettingsError("VioSettings: init.max_keyframes must not exceed window.window_keyframes "
                                "(the window starts with every keyframe of the initialisation)")
        if self.min_tracked_landmarks < 0 or self.history_frames < 1:
            raise SettingsError("VioSettings: min_tracked_landmarks must be >= 0 and history_frames >= 1")
