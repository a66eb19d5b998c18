"""The valid range of every numeric setting, in one table, checked in one place (issue 23).

:data:`SETTING_RANGES` maps ``"SettingsClass.field"`` to an interval
(:class:`vio_core.ranges.Interval`: ``(0, inf)`` finite and > 0, ``[0, 1]``, ``(0, inf]``
where ``inf`` means "no bound"). :func:`check_settings` walks a whole configuration
(pipeline settings and run settings) and refuses the first value outside its range with one
line naming the key path (``rescaler.ransac.inlier_sigmas must be finite and > 0, got inf``);
``vio-depth run`` and ``vio-depth config`` call it on the resolved settings, and
:func:`~vio_depth.run.run_sequence` on what the API hands it. A field without an entry must
at least be finite; ``tests/vio_depth/run/test_ranges.py`` checks that every numeric field
of every preset has an entry and that docs/settings_ranges.md lists this table.

The stages' own ``__post_init__`` checks remain (they also hold for settings built in
code); this table is the complete, documented list. Before it, ``[rescaler.ransac]
inlier_sigmas = inf`` was accepted (AbsRel 0.017 -> 0.047) although docs/safety.md promised
that infinite thresholds are refused.
"""

from __future__ import annotations

import dataclasses
import types
import typing

from vio_core.ranges import Interval, check_ranges

from ..pipeline import PRESET_FAMILIES, PipelineSettings
from .config import RunSettings

#: "SettingsClass.field" -> valid interval (see the module docstring)
SETTING_RANGES: dict[str, str] = {
    # pipeline
    "PipelineSettings.min_matches": "[1, inf)",
    # matchers
    "SiftSettings.max_features": "[1, inf)",
    "SiftSettings.contrast_threshold": "[0, inf)",
    "SiftSettings.edge_threshold": "(0, inf)",
    "SiftSettings.n_octave_layers": "[1, inf)",
    "SiftSettings.sigma": "(0, inf)",
    "SiftSettings.ratio": "(0, 1]",
    "SiftSettings.block_rows": "[1, inf)",
    "GuidedSettings.floor_px": "(0, inf)",
    "GuidedSettings.sigmas": "[0, inf)",
    "GuidedSettings.block_rows": "[1, inf)",
    "LearnedMatcherSettings.detection_threshold": "[-1, 1]",
    "LearnedMatcherSettings.filter_threshold": "[0, 1)",
    "LearnedMatcherSettings.max_keypoints": "[1, inf)",
    "LearnedMatcherSettings.max_side": "[32, inf)",
    "KltSettings.max_tracks": "[1, inf)",
    "KltSettings.top_up_below": "(0, 1]",
    "KltSettings.min_distance_px": "(0, inf)",
    "KltSettings.quality": "(0, 1)",
    "KltSettings.block_size": "[1, inf)",
    "KltSettings.window_px": "[3, inf)",
    "KltSettings.pyramid_levels": "[0, inf)",
    "KltSettings.max_iterations": "[1, inf)",
    "KltSettings.back_check_px": "[0, inf)",
    "KltSettings.ransac_px": "(0, inf)",
    "KltSettings.ransac_hypotheses": "[1, inf)",
    "KltSettings.border_px": "[0, inf)",
    "KltSettings.seed": "[0, inf)",
    # pairing
    "PairingSettings.min_rotation_deg": "(0, 180]",
    "PairingSettings.min_translation_m": "(0, inf)",
    "PairingSettings.keyframe_fraction": "(0, 1]",
    "PairingSettings.buffer_size": "[1, inf)",
    "PairingSettings.pairs_per_frame": "[1, inf)",
    "PairingSettings.max_pair_error": "(0, inf)",
    "PairingSettings.expected_depth_m": "(0, inf)",
    "ConsistencySettings.max_residual_px": "(0, inf)",
    "ConsistencySettings.refuse_probability": "(0.5, 1)",
    "ConsistencySettings.window": "[1, inf)",
    "ConsistencySettings.prior_pairs": "(0, inf)",
    "ConsistencySettings.max_inflation": "[1, inf)",
    "PoseUncertainty.rotation_deg": "[0, inf)",
    "PoseUncertainty.rotation_fraction": "[0, inf)",
    "PoseUncertainty.translation_m": "[0, inf)",
    "PoseUncertainty.translation_fraction": "[0, inf)",
    "PoseUncertainty.time_jitter_s": "[0, inf)",
    # triangulation
    "TriangulationSettings.max_sampson_px": "(0, inf)",
    "TriangulationSettings.max_reprojection_px": "(0, inf)",
    "TriangulationSettings.min_angle_deg": "[0, 90)",
    "TriangulationSettings.min_depth_m": "[0, inf)",
    "TriangulationSettings.max_depth_m": "(0, inf)",
    "TriangulationSettings.pixel_sigma_px": "[0, inf)",
    "MultiviewSettings.pixel_sigma_px": "(0, inf)",
    "MultiviewSettings.max_residual_sigmas": "(0, inf)",
    "MultiviewSettings.outlier_rounds": "[0, inf)",
    "MultiviewSettings.max_relative_sigma": "(0, inf)",
    "MultiviewSettings.min_depth_m": "[0, inf)",
    "MultiviewSettings.max_depth_m": "(0, inf)",
    # rescaling
    "RescalerSettings.max_fallback_age": "[1, inf)",
    "RescalerSettings.max_fallback_error": "(0, inf]",  # inf: no bound (benchmarks/bench_fallback.py)
    "RescalerSettings.max_fit_error": "(0, inf]",  # inf: no bound
    "RescalerSettings.predicted_error_max_depth": "(0, inf]",  # inf: every pixel with depth
    "RescalerSettings.max_disparity_spread": "(0, inf]",  # None: every point fitted
    "RescalerSettings.spread_radius_px": "[1, inf)",
    "RansacSettings.inlier_sigmas": "(0, inf)",
    "RansacSettings.model_relative_sigma": "(0, inf)",
    "RansacSettings.min_sigma_disparity": "(0, inf)",
    "RansacSettings.confidence": "(0, 1)",
    "RansacSettings.min_iterations": "[1, inf)",
    "RansacSettings.max_iterations": "[1, inf)",
    "RansacSettings.batch_size": "[1, inf)",
    "RansacSettings.score_points": "[1, inf)",
    "RansacSettings.lo_iterations": "[0, inf)",
    "RansacSettings.reweight_tolerance": "[0, inf)",
    "RansacSettings.seed": "[0, inf)",
    "RansacSettings.min_points": "[2, inf)",
    "RansacSettings.min_inliers": "[2, inf)",
    "RansacSettings.min_inlier_ratio": "[0, 1]",
    "RansacSettings.min_relative_spread": "[0, inf)",
    "RansacSettings.scale_only_min_points": "[1, inf)",
    "RansacSettings.scale_confidence": "[0, 1)",
    "KalmanSettings.process_sigma": "[0, inf)",
    "KalmanSettings.measurement_floor": "[0, inf)",
    "KalmanSettings.min_reference_fraction": "(0, 1]",
    "KalmanSettings.measurement_noise_scale": "(0, inf)",
    "KalmanSettings.gate_probability": "(0, 1)",
    "KalmanSettings.reset_after_rejections": "[1, inf)",
    "KalmanSettings.max_steps_without_update": "[0, inf)",
    "KalmanSettings.anchor_quantiles": "[0, 1]",
    # points, disparity, model
    "PointSourceSpec.seed": "[0, inf)",
    "DisparitySettings.seed": "[0, inf)",
    "DisparitySettings.min_valid_fraction": "[0, 1]",
    "DepthAnythingSettings.input_size": "[14, 4096]",
    # poses: IMU preintegration
    "ImuPoseSettings.max_interval_s": "(0, inf)",
    "ImuPoseSettings.max_sample_gap_s": "(0, inf)",
    "ImuPoseSettings.integration_sigma": "[0, inf)",
    "ImuPoseSettings.given_velocity_sigma": "(0, inf)",
    "ImuPoseSettings.static_window_s": "(0, inf)",
    "ImuPoseSettings.accel_bias": "[-100, 100]",  # m/s^2: MEMS biases are < 1
    "ImuPoseSettings.gyro_bias": "[-10, 10]",  # rad/s: MEMS biases are < 0.1
    "ImuPoseSettings.bias_window_s": "[0, inf)",  # 0 disables the fit
    "ImuPoseSettings.min_window_frames": "[1, inf)",
    "ImuPoseSettings.min_fit_imu_rate_hz": "[0, inf)",
    "ImuPoseSettings.accel_bias_prior_sigma": "(0, inf)",
    "ImuPoseSettings.gyro_bias_prior_sigma": "(0, inf)",
    "ImuPoseSettings.pose_sigma_m": "(0, inf)",
    "ImuPoseSettings.pose_sigma_rad": "(0, inf)",
    "ImuPoseSettings.accel_noise_scale": "(0, inf)",
    "ImuPoseSettings.gyro_noise_scale": "(0, inf)",
    "ImuPoseSettings.bias_scatter_window_s": "[0, inf)",
    "ImuPoseSettings.velocity_pose_sigma_m": "(0, inf)",
    # poses: visual-inertial odometry
    "VioSettings.velocity_sigma": "(0, inf)",
    "VioSettings.max_scale_sigma": "(0, inf)",
    "VioSettings.min_span_sigma_m": "(0, inf)",
    "VioSettings.gauge_sigma_m": "(0, inf)",
    "VioSettings.gauge_yaw_sigma_rad": "(0, inf)",
    "VioSettings.tilt_sigma_rad": "(0, inf)",
    "VioSettings.max_speed_m_s": "(0, inf)",
    "VioSettings.max_accel_bias": "(0, inf)",
    "VioSettings.max_gyro_bias": "(0, inf)",
    "VioSettings.max_imu_only_s": "(0, inf)",
    "VioSettings.min_tracked_landmarks": "[0, inf)",
    "VioSettings.epipolar_threshold_px": "(0, inf)",
    "VioSettings.predict_velocity_sigma": "(0, inf)",
    "VioSettings.predict_gyro_sigma": "(0, inf)",
    "VioSettings.history_frames": "[1, inf)",
    "RestSettings.max_speed_m_s": "(0, inf)",
    "RestSettings.imu_noise_multiplier": "(0, inf)",
    "RestSettings.chi2_probability": "(0, 1)",
    "RestSettings.tilt_sigma_rad": "(0, inf)",
    "RestSettings.accel_bias_sigma": "(0, inf)",
    "WindowBackendSettings.lag_frames": "[1, 1000]",
    "WindowBackendSettings.start_lag_frames": "[0, 1000]",
    "WindowBackendSettings.init_lag_frames": "[0, 1000]",
    "WindowBackendSettings.catch_up_keyframes": "[0, 100]",
    "WindowBackendSettings.max_pending_keyframes": "[1, 100]",
    "RestSettings.gyro_bias_sigma": "(0, inf)",
    "RestSettings.min_imu_s": "(0, inf)",
    "RestSettings.imu_block_s": "(0, inf)",
    "RestSettings.max_disparity_px": "(0, inf)",
    "RestSettings.max_anchor_motion": "(0, inf)",
    "RestSettings.anchor_motion_sigmas": "[0, inf)",
    "RestSettings.gyro_bias_window_s": "(0, inf)",
    "RestSettings.min_features": "[5, inf)",
    "RestSettings.translation_random_walk": "(0, inf)",
    "RestSettings.rotation_random_walk": "(0, inf)",
    "VioInitSettings.still_flow_px": "(0, inf)",
    "VioInitSettings.lookback_s": "(0, inf)",
    "VioInitSettings.min_parallax_deg": "(0, 180)",
    "VioInitSettings.min_duration_s": "(0, inf)",
    "VioInitSettings.max_duration_s": "(0, inf)",
    "VioInitSettings.max_gravity_error": "(0, inf)",
    "VioInitSettings.max_gyro_bias": "(0, inf)",
    "VioInitSettings.max_keyframes": "[3, inf)",
    "VioInitSettings.min_keyframes": "[3, inf)",
    "VioInitSettings.max_residual_px": "(0, inf)",
    "VioInitSettings.max_scale_change": "(0, inf)",
    "VioInitSettings.max_scale_sigma": "(0, inf)",
    "VioInitSettings.min_acceleration": "[0, inf)",
    "VioInitSettings.min_landmarks": "[8, inf)",
    "StaticInitSettings.window_s": "(0, inf)",
    "StaticInitSettings.accel_tolerance": "(0, inf)",
    "StaticInitSettings.gyro_tolerance": "(0, inf)",
    "StaticInitSettings.max_gravity_mismatch": "(0, inf)",
    "StaticInitSettings.max_gyro_rate": "(0, inf)",
    "StaticInitSettings.min_still_s": "(0, inf)",
    "StaticInitSettings.start_s": "[0, inf)",
    # landmarks (--points landmarks and the odometry's window)
    "LandmarkSettings.window_keyframes": "[2, inf)",
    "LandmarkSettings.match_keyframes": "[1, inf)",
    "LandmarkSettings.refresh_keyframes": "[1, inf)",
    "LandmarkSettings.min_track_length": "[2, inf)",
    "LandmarkSettings.huber_sigmas": "(0, inf)",
    "LandmarkSettings.ba_relative_sigma_factor": "(0, inf)",
    "LandmarkSettings.keyframe_relative_sigma": "(0, inf)",
    "LandmarkSettings.keyframe_min_tracked_fraction": "[0, 1]",
    "LandmarkSettings.max_keyframe_gap": "[1, inf)",
    "LandmarkSettings.ba_max_landmarks": "[1, inf)",
    "LandmarkSettings.lm_max_iterations": "[1, inf)",
    "LandmarkSettings.lm_min_error_decrease": "[0, inf)",
    "LandmarkSettings.query_max_iterations": "[0, inf)",
    "LandmarkSettings.min_query_points": "[3, inf)",
    "PosePriorSettings.absolute_rotation_deg": "(0, inf)",
    "PosePriorSettings.absolute_translation_m": "(0, inf)",
    "PosePriorSettings.relative_rotation_deg": "(0, inf)",
    "PosePriorSettings.relative_translation_m": "(0, inf)",
    "PosePriorSettings.relative_translation_fraction": "[0, inf)",
    "PosePriorSettings.relative_translation_axes": "(0, inf)",
    # poses: the offline pose calibration (--calibrate-poses)
    "PoseCalibrationSettings.anchors": "[1, inf)",
    "PoseCalibrationSettings.pair_gaps_s": "(0, inf)",
    "PoseCalibrationSettings.min_baseline_m": "(0, inf)",
    "PoseCalibrationSettings.min_matches": "[8, inf)",
    "PoseCalibrationSettings.max_matches_per_pair": "[1, inf)",
    "PoseCalibrationSettings.min_pairs": "[1, inf)",
    "PoseCalibrationSettings.gate_px": "(0, inf)",
    "PoseCalibrationSettings.regate_sigmas": "(0, inf)",
    "PoseCalibrationSettings.min_gate_px": "(0, inf)",
    "PoseCalibrationSettings.huber_sigmas": "(0, inf)",
    "PoseCalibrationSettings.pixel_sigma_px": "(0, inf)",
    "PoseCalibrationSettings.time_offset_search_s": "[0, inf)",
    "PoseCalibrationSettings.time_offset_search_step_s": "[0, inf)",
    "PoseCalibrationSettings.prior_rotation_deg": "(0, inf)",
    "PoseCalibrationSettings.prior_translation_m": "(0, inf)",
    "PoseCalibrationSettings.prior_time_offset_s": "(0, inf)",
    "PoseCalibrationSettings.max_iterations": "[1, inf)",
    "PoseCalibrationSettings.significance_sigmas": "(0, inf)",
    "PoseCalibrationSettings.min_time_offset_s": "[0, inf)",
    "PoseCalibrationSettings.min_rotation_deg": "[0, inf)",
    "PoseCalibrationSettings.min_translation_m": "[0, inf)",
    "PoseCalibrationSettings.max_time_offset_sigma_s": "(0, inf)",
    "PoseCalibrationSettings.max_rotation_sigma_deg": "(0, inf)",
    "PoseCalibrationSettings.max_translation_sigma_m": "(0, inf)",
    # run and outputs
    "RunSettings.max_frames": "[0, inf)",  # 0 = all frames
    "RunSettings.min_eval_depth": "[0, inf)",
    "RunSettings.max_eval_depth": "(0, inf)",
    "RunSettings.rpe_delta_m": "(0, inf)",
    "RunSettings.min_depth_fraction": "[0, 1]",
    "ExportSettings.thumbnail_width": "[16, 4096]",
    "PlySettings.dense_stride": "[1, inf)",
    "PlySettings.dense_max_depth": "(0, inf)",
    "PreviewSettings.percentiles": "[0, 100]",
    "PreviewSettings.invalid_rgb": "[0, 255]",
    "PreviewSettings.error_range": "(0, inf)",
    "PreviewSettings.depth_range": "(0, inf)",
}


def check_settings(pipeline, run=None) -> None:
    """Refuse the first numeric setting of ``pipeline`` (a
    :class:`~vio_depth.pipeline.PipelineSettings`) or ``run`` (a :class:`RunSettings`)
    outside its range in :data:`SETTING_RANGES`.

    Raises:
        SettingsError: naming the key path (``rescaler.ransac.inlier_sigmas``), the value
            and the valid range.
    """
    check_ranges(pipeline, SETTING_RANGES)
    if run is not None:
        check_ranges(run, SETTING_RANGES, where="run")


def _trees():
    """The default configuration and every preset of every family, each with its TOML table."""
    yield "", PipelineSettings()
    yield "run", RunSettings()
    for family, presets in PRESET_FAMILIES.items():
        for name in presets:
            yield family, presets[name]


def _field_paths(cls, where: str, out: dict[str, set[str]], depth: int = 0) -> None:
    """``"Class.field" -> TOML key paths`` of every field of the settings class ``cls``,
    following the type hints (so optional nested settings count too)."""
    if depth > 8:
        return
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        path = f"{where}.{f.name}" if where else f.name
        tp = hints[f.name]
        args = typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,)
        nested = [a for a in args if dataclasses.is_dataclass(a)]
        for a in nested:
            _field_paths(a, path, out, depth + 1)
        if not nested:
            out.setdefault(f"{cls.__name__}.{f.name}", set()).add(path)


def describe_ranges() -> str:
    """The table as Markdown, with the TOML keys each entry checks (docs/settings_ranges.md
    lists it)."""
    paths: dict[str, set[str]] = {}
    for where, tree in _trees():
        _field_paths(type(tree), where, paths)
    lines = ["| TOML key(s) | settings field | valid range |", "|---|---|---|"]
    for key, text in SETTING_RANGES.items():
        keys = ", ".join(f"`{p}`" for p in sorted(paths.get(key, ())))
        lines.append(f"| {keys} | `{key}` | {Interval.parse(text).describe()} |")
    return "\n".join(lines)


__all__ = ["SETTING_RANGES", "check_settings", "describe_ranges"]
