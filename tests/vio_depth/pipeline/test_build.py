"""The builder: each pose source and points stage is chosen by explicit settings, in one place."""

from dataclasses import replace

import numpy as np
import pytest

from matchers import SiftMatcher
from vio_core import Camera, InputError, SettingsError, UnknownNameError
from vio_depth.frame import Frame, ImuData
from vio_depth.pipeline import (
    POSE_PRESETS,
    VIO_CAMERA_RATE,
    FrameStream,
    LandmarkPointsStage,
    Pipeline,
    PipelineSettings,
    PoseStage,
    SourceLandmarkPoints,
    TwoViewPoints,
    build_points_stage,
    build_pose_stage,
    build_stages,
    create_pose_source,
)
from vio_depth.pipeline.feed import NO_SAMPLES_YET, LazyImuPoses, StreamInputs
from vio_depth.poses import GroundTruthPoses, GroundTruthPoseSettings, ImuPoseSettings, ImuPoseSource
from vio_depth.vio import VioEstimator, VioPoseSource, VioSettings

CAM = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)


def _imu(t0: float = 0.0, t1: float = 2.0) -> ImuData:
    """A still IMU at 200 Hz (z up): enough for the sources to be built."""
    t = np.arange(t0, t1, 0.005)
    return ImuData(t, np.zeros((len(t), 3)), np.tile([0.0, 0.0, 9.81], (len(t), 1)), np.eye(4))


class _Sequence:
    root = "/data/seq"
    pose_kind = "ins"
    imu_missing_reason = "the dataset has no gyroscope"

    def __init__(self, imu):
        self.imu = imu


def _no_disparity(frame):
    return None


def _frame(index: int, t: float) -> Frame:
    return Frame(index, t, f"{index:06d}", CAM, np.eye(4), load_image=lambda: np.zeros((6, 8, 3), np.uint8))


def test_each_pose_preset_builds_its_source_from_its_settings_type():
    assert list(POSE_PRESETS) == ["gt", "imu", "imu_real_mav", "vio", "vio_offline", "vio_realtime"]
    assert POSE_PRESETS.default == "gt"
    assert POSE_PRESETS["vio_offline"] == VioSettings() and POSE_PRESETS["imu"] == ImuPoseSettings()
    # --poses vio is the camera-rate configuration; vio_realtime, its former name, the same settings
    realtime = POSE_PRESETS["vio"]
    assert POSE_PRESETS["vio_realtime"] == realtime == VIO_CAMERA_RATE
    assert realtime.backend.kind == "process" and realtime.backend.lag_frames == 4
    # and only that, iSAM2 and bridges once (docs/benchmarks.md "vio_realtime's worker ...")
    assert realtime.window.solver == "isam2" and VioSettings().window.solver == "batch"
    assert realtime.window.gate_extended_tracks and not VioSettings().window.gate_extended_tracks
    assert realtime.window.ba_max_landmarks == 600 and VioSettings().window.ba_max_landmarks == 800
    assert realtime.bridge_every_update is False and VioSettings().bridge_every_update is True
    assert realtime.defer_bridge_refresh and not VioSettings().defer_bridge_refresh
    assert replace(realtime, backend=VioSettings().backend, window=VioSettings().window,
                   bridge_every_update=True, defer_bridge_refresh=False) == VioSettings()
    seq = _Sequence(_imu())
    gt = build_pose_stage("gt", seq)
    assert isinstance(gt.source, GroundTruthPoses) and gt.tracker is None
    assert gt.source.pose_kind == "ins"  # the sequence's kind of poses
    assert build_pose_stage(GroundTruthPoseSettings()).source.pose_kind == "exact"
    imu = build_pose_stage("imu_real_mav", seq)
    assert isinstance(imu.source, ImuPoseSource) and imu.tracker is None
    assert imu.source.settings == ImuPoseSettings(accel_noise_scale=10.0)
    matcher = SiftMatcher()
    vio = build_pose_stage(VioSettings(), seq, matcher)
    assert isinstance(vio.source, VioPoseSource) and vio.tracker is vio.source and vio.source.matcher is matcher
    assert isinstance(create_pose_source("vio", seq).matcher, SiftMatcher)  # default matcher of the API


def test_unknown_pose_sources_and_missing_imu_are_clear_errors():
    with pytest.raises(UnknownNameError, match="gt, imu, imu_real_mav, vio"):
        build_pose_stage("gps")
    with pytest.raises(ValueError, match="GroundTruthPoseSettings, ImuPoseSettings, VioSettings"):
        build_pose_stage(object())  # settings of no source: a SettingsError (a ValueError)
    for name in ("imu", "vio"):
        with pytest.raises(InputError, match=f"no IMU.*--poses {name} is not possible.*no gyroscope"):
            build_pose_stage(name, _Sequence(None))
        with pytest.raises(InputError, match=f"the {name} pose source needs imu_calibration"):
            build_pose_stage(name, stream=StreamInputs())


def test_the_pose_choice_reaches_the_estimator_by_explicit_calls():
    """``--poses vio`` -> POSE_PRESETS["vio"] -> build_stages -> VioPoseSource -> VioEstimator."""
    settings = PipelineSettings.from_presets(poses="vio")
    pipeline = Pipeline(settings, disparity_source=_no_disparity, sequence=_Sequence(_imu()))
    assert isinstance(pipeline.tracker, VioPoseSource) and pipeline.tracker is pipeline.pose_source
    assert isinstance(pipeline.tracker.estimator, VioEstimator)
    assert pipeline.tracker.matcher is pipeline.matcher and isinstance(pipeline.matcher, SiftMatcher)
    assert pipeline.fresh().tracker is pipeline.tracker
    assert len(pipeline.workers) == 1  # the odometry's window in a worker process, until closed
    pipeline.close()
    assert all(not w.alive for w in pipeline.workers)


def test_stream_sources_are_built_when_the_first_imu_samples_arrive():
    inputs = StreamInputs("exact", _imu(0.0, 0.01))
    stage = build_pose_stage("imu", stream=inputs)
    lazy = stage.source
    assert isinstance(lazy, LazyImuPoses) and stage.tracker is None
    inputs.frames += [_frame(0, 0.1), _frame(1, 0.2)]
    rel = lazy.relative(inputs[0], inputs[1])
    assert not rel.ok and rel.reason == NO_SAMPLES_YET and lazy.source is None
    first = _imu(0.0, 0.15)
    inputs.add_imu(first.t, first.gyro, first.accel)
    lazy.relative(inputs[0], inputs[1])
    built = lazy.source
    assert isinstance(built, ImuPoseSource) and len(built.imu.t) == len(first.t)
    more = _imu(0.15, 0.3)
    inputs.add_imu(more.t, more.gyro, more.accel)
    lazy.relative(inputs[0], inputs[1])
    assert lazy.source is built and len(built.imu.t) == len(first.t) + len(more.t)  # the grown samples

    matcher = SiftMatcher()
    vio = build_pose_stage("vio", matcher=matcher, stream=StreamInputs("exact", _imu(0.0, 0.01)))
    assert isinstance(vio.source, LazyImuPoses) and vio.tracker is vio.source and vio.source.matcher is matcher
    pose = vio.tracker.track(_frame(0, 0.1), None)
    assert not pose.ok and pose.status == "initialising" and pose.reason == NO_SAMPLES_YET


def test_frame_stream_builds_through_the_builder():
    cal = _imu(0.0, 0.01)
    imu = FrameStream(CAM, PipelineSettings.from_presets(poses="imu"), imu_calibration=cal).pipeline
    assert isinstance(imu.pose_source, LazyImuPoses) and imu.tracker is None
    assert imu.fresh().tracker is None  # the stage, not the wrapper's methods, says whether it tracks
    vio = FrameStream(CAM, PipelineSettings.from_presets(poses="vio_offline"), imu_calibration=cal).pipeline
    assert isinstance(vio.tracker, LazyImuPoses) and vio.tracker.matcher is vio.matcher is not None
    gt = FrameStream(CAM, PipelineSettings.from_presets(points="lidar:16"), pose_kind="mocap").pipeline
    assert isinstance(gt.pose_source, GroundTruthPoses) and gt.pose_source.pose_kind == "mocap"
    assert gt.matcher is None and gt.points is None  # no stage needs features


def test_each_points_stage_is_chosen_by_the_points_settings():
    gt = GroundTruthPoses()
    matcher = SiftMatcher()
    for points, kind in (("sfm", TwoViewPoints), ("landmarks", LandmarkPointsStage)):
        stage = build_points_stage(PipelineSettings.from_presets(points=points), gt, matcher)
        assert isinstance(stage, kind) and stage.matcher is matcher
    for points in ("lidar:16", "random:100"):
        assert build_points_stage(PipelineSettings.from_presets(points=points), gt, None) is None
    imu = ImuPoseSource(_imu())
    # any other source's relative poses and their covariance become the window's motion factors
    stage = build_points_stage(PipelineSettings.from_presets(poses="imu", points="landmarks"), imu, matcher)
    assert isinstance(stage, SourceLandmarkPoints) and stage.matcher is matcher
    # a points window in a worker takes the sequence's poses as priors; motion factors are built here
    in_worker = PipelineSettings.from_dict({"landmarks_backend": {"kind": "process"}},
                                           PipelineSettings.from_presets(poses="imu", points="landmarks"))
    with pytest.raises(SettingsError, match=r"only with the sequence's poses \(--poses gt\)"):
        build_points_stage(in_worker, imu, matcher)
    # the odometry's own landmarks: only under --poses vio
    for poses, source in (("gt", gt), ("imu", imu)):
        with pytest.raises(SettingsError, match="--points vio takes the odometry's own landmarks"):
            build_points_stage(PipelineSettings.from_presets(poses=poses, points="vio"), source, matcher)
    with pytest.raises(UnknownNameError, match="sfm"):
        PipelineSettings.from_presets(points="lidar_beams")


def test_stages_build_a_matcher_only_where_one_is_needed_and_share_it():
    gt = GroundTruthPoses()
    stages = build_stages(PipelineSettings.from_presets(points="lidar:16"), poses=gt, disparity_source=_no_disparity)
    assert stages.matcher is None and stages.points is None and stages.poses == PoseStage(gt)
    stages = build_stages(PipelineSettings(), poses=gt, disparity_source=_no_disparity)
    assert isinstance(stages.matcher, SiftMatcher) and stages.points.matcher is stages.matcher
    tracker = build_pose_stage("vio_offline", _Sequence(_imu()), SiftMatcher())
    stages = build_stages(PipelineSettings.from_presets(poses="vio_offline"), poses=tracker.source,
                          disparity_source=_no_disparity)
    assert stages.poses == tracker and stages.matcher is tracker.source.matcher  # the tracker's own matcher
    with pytest.raises(InputError, match="must use the pipeline's matcher"):
        build_stages(PipelineSettings(), poses=tracker, disparity_source=_no_disparity, matcher=SiftMatcher())
