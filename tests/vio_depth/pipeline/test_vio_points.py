"""``--points vio`` (the odometry's own landmarks feed the rescaler, no second matching) and
``--points landmarks`` with a relative pose source (``imu``), on the bundled SIMULATED samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from matchers import create_matcher
from vio_core import SettingsError
from vio_depth import Pipeline, PipelineSettings, open_sequence
from vio_depth.cli import main
from vio_depth.pipeline import FrameStatus
from vio_depth.pipeline.source_landmarks import SourceLandmarkPoints
from vio_depth.pipeline.vio_points import VioPoints
from vio_depth.rescale import Rescaler, RescalerSettings, sample_bilinear
from vio_depth.run import RunSettings, read_frames_jsonl, run_sequence

REPO = Path(__file__).resolve().parents[3]
ROOM = REPO / "sample_sequences" / "room"
STREET = REPO / "sample_sequences" / "street"
pytestmark = pytest.mark.skipif(not (ROOM / "sequence.json").exists(), reason="bundled samples missing")
pytest.importorskip("gtsam")
N = 30  # the room sample's dynamic start needs about 25 frames


class CountingMatcher:
    """A matcher that counts its ``match`` calls (the odometry's and any stage's)."""

    def __init__(self, inner):
        self.inner = inner
        self.name = inner.name
        self.concurrent_extract = inner.concurrent_extract
        self.calls = 0

    def extract(self, image):
        return self.inner.extract(image)

    def match(self, a, b):
        self.calls += 1
        return self.inner.match(a, b)


@pytest.fixture(scope="module")
def room_vio():
    """The first N room frames under --poses vio --points vio: (sequence, pipeline, results,
    matcher calls inside the points stage, matcher calls in all)."""
    seq = open_sequence(ROOM)
    matcher = CountingMatcher(create_matcher("sift"))
    pipe = Pipeline(PipelineSettings.from_presets(poses="vio_offline", points="vio", pairing="indoor"), sequence=seq,
                    matcher=matcher)  # the odometry inline: its landmarks in the frame that tracked them
    stage_calls = []
    process = pipe.points.process

    def counted(*args, **kwargs):
        before = matcher.calls
        out = process(*args, **kwargs)
        stage_calls.append(matcher.calls - before)
        return out

    pipe.points.process = counted
    results = [pipe.process(seq[i]) for i in range(N)]
    return seq, pipe, results, stage_calls, matcher.calls


def test_vio_points_are_the_odometrys_landmarks_without_matching(room_vio):
    seq, pipe, results, stage_calls, total_calls = room_vio
    assert isinstance(pipe.points, VioPoints)
    assert len(stage_calls) == N and sum(stage_calls) == 0  # the points stage matched nothing
    assert total_calls > N  # the odometry did (the same matcher, extracted once per frame)
    ok = [r for r in results if r.points.status == FrameStatus.OK]
    assert len(ok) >= 4
    estimator = pipe.pose_source.estimator
    for r in ok:
        seen = estimator.frame_landmarks(r.frame)
        np.testing.assert_array_equal(r.points.depth, seen.points.depth)
        np.testing.assert_array_equal(r.points.uv, seen.points.uv)
        np.testing.assert_array_equal(r.points.sigma, seen.points.sigma_depth)
        assert r.points.depth_shared.shape == (len(r.points.depth), 7)
        assert np.all(r.points.sigma > 0)
        # metric: the landmarks' depths agree with the ground truth within a few sigma
        gt, inside = sample_bilinear(seq[r.frame].gt_depth(), r.points.uv)
        good = inside & (gt > 0)
        rel = np.abs(r.points.depth[good] - gt[good]) / gt[good]
        assert np.median(rel) < 0.02
    with_depth = [r for r in ok if r.has_depth]
    assert with_depth and all(r.rescale.predicted_error <= 0.03 for r in with_depth)
    assert all(r.rescale.predicted_pose_error > 0 for r in with_depth)  # the shared columns count
    # frames before the odometry's start: no pose, with its reason
    assert results[0].status == FrameStatus.NO_POSE and "initialising" in results[0].reason


def test_vio_points_shared_error_drives_the_refusal(room_vio):
    """A tight max_fit_error refuses the frames whose shared (pose and scale) error alone exceeds it."""
    seq, pipe, results, _, _ = room_vio
    r = next(r for r in results if r.has_depth and not r.points.landmarks.keyframe)
    d, inside = sample_bilinear(r.disparity, r.points.uv)
    args = (d[inside], r.points.depth[inside], r.points.sigma[inside])
    shared = r.points.depth_shared[inside]
    loose = Rescaler(RescalerSettings(temporal=None, fallback=False)).update(*args, disparity_map=r.disparity,
                                                                             depth_shared=shared)
    assert loose.fit is not None and loose.predicted_pose_error > 0
    bound = 0.5 * loose.predicted_pose_error
    tight = Rescaler(RescalerSettings(temporal=None, fallback=False, max_fit_error=bound)).update(
        *args, disparity_map=r.disparity, depth_shared=shared)
    assert tight.fit is None and "pose uncertainty alone" in tight.reason
    # without the shared columns the same points would pass: they are what refuses the frame
    alone = Rescaler(RescalerSettings(temporal=None, fallback=False)).update(*args, disparity_map=r.disparity)
    assert alone.predicted_error < loose.predicted_error


@pytest.mark.parametrize("poses", ["gt", "imu"])
def test_vio_points_need_the_odometry(poses):
    seq = open_sequence(STREET)
    with pytest.raises(SettingsError, match="--poses vio"):
        Pipeline(PipelineSettings.from_presets(points="vio", poses=poses), sequence=seq)


def test_vio_points_with_another_pose_source_one_clear_line(tmp_path, capsys):
    rc = main(["run", str(STREET), "--points", "vio", "--max-frames", "2", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1 and "--points vio" in err and "--poses vio" in err
    assert not (tmp_path / "out").exists()


def test_landmarks_with_imu_poses_use_their_covariance():
    seq = open_sequence(STREET)
    pipe = Pipeline(PipelineSettings.from_presets(points="landmarks", poses="imu"), sequence=seq)
    assert isinstance(pipe.points, SourceLandmarkPoints)
    # the first landmarks come with the second keyframe (frame 6 here since keyframe_relative_sigma
    # 0.12; 5 at 0.15: no backward pass), the third keyframe at frame 11
    results = [pipe.process(seq[i]) for i in range(12)]
    ok = [r for r in results if r.points.status == FrameStatus.OK]
    assert len(ok) >= 5 and sum(r.points.landmarks.keyframe for r in results) >= 3
    for r in ok:
        gt, inside = sample_bilinear(seq[r.frame].gt_depth(), r.points.uv)
        good = inside & (gt > 0)
        assert np.median(np.abs(r.points.depth[good] - gt[good]) / gt[good]) < 0.03
        # the window's scale comes from the IMU's relative translations: a shared error > 0
        assert np.all(r.points.depth_shared[:, 6] > 0)
    assert sum(r.has_depth for r in results) >= 5


def test_frame_stream_takes_vio_points_before_any_imu_sample():
    """The stream's odometry is created with the first IMU samples: until then its frames get
    no pose (not an exception), and the stage is the vio one from the start."""
    from vio_depth import FrameStream

    seq = open_sequence(ROOM)
    stream = FrameStream(seq.camera, PipelineSettings.from_presets(poses="vio", points="vio", pairing="indoor"),
                         imu_calibration=seq.imu)
    assert isinstance(stream.pipeline.points, VioPoints)
    frame = seq[0]
    res = stream.push(frame.image(), np.ones((seq.camera.height, seq.camera.width), np.float32),
                      timestamp=frame.timestamp)
    assert res.points.status == FrameStatus.NO_POSE and "no IMU samples" in res.points.reason
    assert res.depth is None


def test_the_backward_pass_pairs_the_leading_frames_two_view_with_the_odometrys_poses(tmp_path):
    """The odometry's landmarks exist only for the frames it tracked live; the leading frames,
    posed only once its start succeeded, get their depth in the offline backward pass from
    two-view points with those poses (before: 5 of the first 22 room frames, now all 22;
    street under vio_realtime, now vio: 71 -> 105 of 130 frames written, none wrong). 60 frames:
    the camera-rate odometry's start is taken over at frame 44."""
    seq = open_sequence(ROOM)
    settings = PipelineSettings.for_pose_source("vio", pairing="indoor")  # klt, the odometry's landmarks
    assert settings.points.kind.value == "vio"
    with Pipeline(settings, sequence=seq) as pipe:
        backward = pipe.fresh(inline_window=True, offline_points=True)
        assert backward.settings.points.kind.value == "sfm" and backward.points.matcher is pipe.matcher
        run_sequence(seq, pipe, tmp_path / "out", RunSettings(max_frames=60))
    _, frames = read_frames_jsonl(tmp_path / "out" / "frames.jsonl")
    backfilled = [f for f in frames if f.get("backfilled") and f["alpha"] is not None]
    forward = [f for f in frames if not f.get("backfilled") and f["alpha"] is not None]
    assert forward and all(f["point_source"] == "vio" for f in forward)
    first_forward = min(f["frame"] for f in forward)
    assert len(backfilled) >= 0.8 * first_forward, (len(backfilled), first_forward)
    assert all(f["point_source"] == "sfm" and f["abs_rel"] < 0.04 for f in backfilled)
