"""A tracking matcher (KLT) in the pipeline: frames in order, the rotation from the right source,
tracks restarted where frames do not follow, and whole runs with depth."""

from pathlib import Path

import numpy as np
import pytest

from matchers import Features, MotionHint, create_matcher
from vio_depth import FrameStream, Pipeline, PipelineSettings, open_sequence
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.frame import Frame
from vio_depth.pipeline.tracking import TrackedExtraction
from vio_depth.poses.gyro import camera_rotation

ROOT = Path(__file__).resolve().parents[3]
STREET = ROOT / "sample_sequences" / "street"
ROOM = ROOT / "sample_sequences" / "room"
pytestmark = pytest.mark.skipif(not (ROOM / "sequence.json").exists(), reason="bundled samples missing")


class RecordingTracker:
    """A stand-in tracker that records the hints and resets it gets."""

    name = "recording"
    concurrent_extract = False

    def __init__(self):
        self.hints: list[MotionHint | None] = []
        self.resets = 0

    def extract(self, image):
        raise AssertionError("a tracker is called through track()")

    def track(self, image, hint=None) -> Features:
        self.hints.append(hint)
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 0), np.float32), np.zeros(0, np.float32), (4, 4))

    def match(self, a, b):
        raise AssertionError("not used")

    def reset(self) -> None:
        self.resets += 1


def test_rotation_comes_from_the_poses_under_gt_and_from_the_gyroscope_otherwise():
    seq = open_sequence(ROOM)
    frames = [seq[i] for i in range(3)]
    image = np.zeros((4, 4, 3), np.uint8)
    for use_poses in (True, False):
        rec = RecordingTracker()
        ex = TrackedExtraction(rec, lambda: seq.imu, use_poses)
        for f in frames:
            ex(f, image)
        assert rec.resets == 1 and rec.hints[0].R_cur_prev is None
        R = rec.hints[2].R_cur_prev
        if use_poses:
            expected = frames[2].T_w_c[:3, :3].T @ frames[1].T_w_c[:3, :3]
        else:
            expected = camera_rotation(seq.imu, frames[1].timestamp, frames[2].timestamp)
        np.testing.assert_allclose(R, expected, atol=1e-12)
    # the simulated gyroscope agrees with the rendered poses (the prediction is right)
    pose_R = frames[2].T_w_c[:3, :3].T @ frames[1].T_w_c[:3, :3]
    gyro_R = camera_rotation(seq.imu, frames[1].timestamp, frames[2].timestamp)
    assert np.degrees(np.arccos(np.clip((np.trace(pose_R.T @ gyro_R) - 1) / 2, -1, 1))) < 0.05


def test_frames_that_do_not_follow_restart_the_tracks():
    seq = open_sequence(ROOM)
    rec = RecordingTracker()
    ex = TrackedExtraction(rec, lambda: None, use_poses=False)
    image = np.zeros((4, 4, 3), np.uint8)
    for i in (0, 1, 3, 2, 5):  # a gap, then one back (a neighbour: tracked on), then a gap
        ex(seq[i], image)
    assert rec.resets == 3
    assert all(h.R_cur_prev is None for h in rec.hints)  # no IMU: no rotation
    f = seq[7]
    ex(Frame(6, f.timestamp, f.stem, f.camera, f.T_w_c, f.load_image), image)  # index follows, time jumps
    assert rec.resets == 3
    ex(Frame(7, seq[1].timestamp, f.stem, f.camera, f.T_w_c, f.load_image), image)  # index follows, time goes back
    assert rec.resets == 4


def test_backwards_the_rotation_is_the_forward_one_inverted():
    seq = open_sequence(ROOM)
    rec = RecordingTracker()
    image = np.zeros((4, 4, 3), np.uint8)
    for use_poses in (True, False):
        ex = TrackedExtraction(rec, lambda: seq.imu, use_poses)
        forward = ex.rotation(seq[4], seq[5])
        backward = ex.rotation(seq[5], seq[4])
        np.testing.assert_allclose(backward, forward.T, atol=1e-12)
        for i in (6, 5, 4):
            ex(seq[i], image)
        np.testing.assert_allclose(rec.hints[-1].R_cur_prev, backward, atol=1e-12)


def test_klt_pipeline_gives_depth_under_gt_with_the_edge_guard():
    """Without the edge guard the first paired frame (4) was 13 % off with 3.7 % predicted:
    corners on depth edges read the other surface's disparity."""
    import dataclasses

    seq = open_sequence(ROOM)
    settings = PipelineSettings.from_presets(matcher="klt", pairing="indoor")
    settings = dataclasses.replace(settings, rescaler=dataclasses.replace(settings.rescaler, max_disparity_spread=0.1))
    pipeline = Pipeline(settings, sequence=seq)
    assert pipeline.tracked is not None and pipeline.tracked.use_poses
    results = [pipeline.process(seq[i]) for i in range(16)]
    with_depth = [r for r in results if r.depth is not None]
    assert len(with_depth) >= 10
    errors = []
    for r in with_depth:
        gt = seq[r.frame].gt_depth()
        ok = np.isfinite(r.depth) & (gt > 0) & (gt < 10)
        errors.append(float(np.mean(np.abs(r.depth[ok] - gt[ok]) / gt[ok])))
    assert max(errors) < 0.05 and np.median(errors) < 0.02, errors


def test_klt_stream_under_vio_uses_the_pushed_gyroscope():
    seq = open_sequence(ROOM)
    imu = seq.imu
    stream = FrameStream(seq.camera, PipelineSettings.from_presets(matcher="klt", poses="vio", pairing="indoor"),
                         imu_calibration=imu)
    tracked = stream.pipeline.tracked
    assert tracked is not None and not tracked.use_poses
    disparity = create_disparity_source(DisparitySettings(), seq)
    t_prev = -np.inf
    for i in range(3):
        frame = seq[i]
        new = (imu.t > t_prev) & (imu.t <= frame.timestamp)
        t_prev = frame.timestamp
        stream.push(frame.image(), disparity(frame), timestamp=frame.timestamp,
                    imu=(imu.t[new], imu.gyro[new], imu.accel[new]))
    R = tracked.rotation(seq[1], seq[2])
    np.testing.assert_allclose(R, camera_rotation(imu, seq[1].timestamp, seq[2].timestamp), atol=1e-9)


def test_klt_matcher_is_not_shared_by_two_pipelines_silently():
    """Each FrameStream builds its own tracker: two streams never interleave one tracker's state."""
    seq = open_sequence(ROOM)
    settings = PipelineSettings.from_presets(matcher="klt", pairing="indoor")
    a, b = FrameStream(seq.camera, settings), FrameStream(seq.camera, settings)
    assert a.pipeline.matcher is not b.pipeline.matcher
    assert type(create_matcher("klt")).__name__ == "KltTracker"


def test_edge_guard_drops_points_on_depth_edges_before_the_fit():
    """The room's KLT corners: with the guard, the fitted points exclude those whose disparity
    spreads > 10 % within 3 px; without it they are all fitted."""
    import dataclasses

    from vio_depth.rescale import disparity_spread

    seq = open_sequence(ROOM)
    guarded = PipelineSettings.from_presets(matcher="klt", pairing="indoor")  # the tracker's default guard
    assert guarded.rescaler.max_disparity_spread == 0.1
    base = dataclasses.replace(guarded, rescaler=dataclasses.replace(guarded.rescaler, max_disparity_spread=None))
    disparity = create_disparity_source(DisparitySettings(), seq)
    found = {}
    for name, settings in (("off", base), ("on", guarded)):
        p = Pipeline(settings, sequence=seq)
        r = [p.process(seq[i]) for i in range(8)][-1]
        found[name] = r
    off, on = found["off"], found["on"]
    d = disparity(seq[7])
    spread_off = disparity_spread(d, off.points_uv, 3)
    assert (spread_off > 0.1).sum() >= 3  # corners on edges are there
    assert np.all(disparity_spread(d, on.points_uv, 3) <= 0.1)
    assert len(on.points_uv) == int((spread_off <= 0.1).sum())
