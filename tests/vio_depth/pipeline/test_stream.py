"""FrameStream: pushing arrays gives exactly what the pipeline gives on the same frames."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from vio_core import InputError, ShapeError
from vio_depth import FrameStream, Pipeline, PipelineSettings, open_sequence
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.pipeline import FrameStatus
from vio_depth.pipeline.feed import StreamInputs

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"
ROOM = Path(__file__).resolve().parents[3] / "sample_sequences" / "room"
pytestmark = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled samples missing")


def test_pushed_arrays_give_the_same_result_as_the_sequence_pipeline():
    seq = open_sequence(STREET)
    settings = PipelineSettings()
    pipeline = Pipeline(settings, sequence=seq)
    stream = FrameStream(seq.camera, settings)
    disparity = create_disparity_source(DisparitySettings(), seq)
    for i in range(6):
        frame = seq[i]
        a = pipeline.process(frame)
        b = stream.push(frame.image(), disparity(frame), timestamp=frame.timestamp, T_w_c=frame.T_w_c)
        assert a.status == b.status and a.points.partners == b.points.partners
        if a.depth is None:
            assert b.depth is None
        else:
            assert (a.fit.alpha, a.fit.beta) == (b.fit.alpha, b.fit.beta)
            np.testing.assert_array_equal(a.depth, b.depth)
    assert sum(r is not None for r in [a.depth]) == 1  # the last frame has metric depth


def test_imu_samples_pushed_per_frame_drive_the_imu_pose_source():
    seq = open_sequence(ROOM)
    imu = seq.imu
    disparity = create_disparity_source(DisparitySettings(), seq)
    stream = FrameStream(seq.camera, PipelineSettings.from_presets(poses="imu", pairing="indoor"),
                         imu_calibration=imu)
    t_prev = -np.inf
    results = []
    for i in range(0, 24, 2):
        frame = seq[i]
        new = (imu.t > t_prev) & (imu.t <= frame.timestamp + 0.02)
        t_prev = frame.timestamp + 0.02
        results.append(stream.push(frame.image(), disparity(frame), timestamp=frame.timestamp,
                                   T_w_c=frame.T_w_c,
                                   imu=(imu.t[new], imu.gyro[new], imu.accel[new])))
    assert results[0].status == FrameStatus.NO_PAIR
    with_depth = [r for r in results if r.depth is not None]
    # the IMU's covariance is large until its biases and velocity are fitted to the past
    # poses: those frames are refused for their predicted error, the later ones written
    assert len(with_depth) >= len(results) // 3
    assert all(r.rescale.predicted_error <= 0.03 for r in with_depth)
    for r in results[1:]:
        if r.depth is None:
            assert r.status in (FrameStatus.UNCERTAIN_FIT, FrameStatus.POSE_INCONSISTENT), r.reason
    for r in with_depth:  # never confidently wrong: the error is within twice the predicted one
        gt = seq[r.frame * 2].gt_depth()
        ok = np.isfinite(r.depth) & (gt > 0)
        err = float(np.mean(np.abs(r.depth[ok] - gt[ok]) / gt[ok]))
        assert err < 2 * r.rescale.predicted_abs_rel, (r.frame, err, r.rescale.predicted_abs_rel)


def test_bad_pushes_are_refused_with_clear_errors():
    seq = open_sequence(STREET)
    stream = FrameStream(seq.camera)
    image = np.zeros((seq.camera.height, seq.camera.width, 3), np.uint8)
    with pytest.raises(InputError, match="expected"):
        stream.push(image[:10], None)
    stream.push(image, None, timestamp=1.0)
    with pytest.raises(InputError, match="increase"):
        stream.push(image, None, timestamp=0.5)
    with pytest.raises(ShapeError, match="T_w_c"):
        stream.push(image, None, timestamp=2.0, T_w_c=np.eye(3))
    with pytest.raises(InputError, match="imu_calibration"):
        FrameStream(seq.camera, PipelineSettings.from_presets(poses="imu"))


def test_a_long_stream_does_not_keep_the_pixels_of_past_frames():
    """Memory of a stream is flat in the number of pushes: before, every pushed image and depth
    stayed referenced by the stream's inputs (1.3 MiB a 1242x375 push; benchmarks/bench_realtime.py)."""
    import tracemalloc

    seq = open_sequence(STREET)
    cam = seq.camera
    stream = FrameStream(cam, PipelineSettings.from_presets(points="lidar:16"))  # no stage keeps frames
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8)
    depth = np.full((cam.height, cam.width), 10.0, np.float32)
    disparity = np.full((cam.height, cam.width), 0.1, np.float32)
    per_push = image.nbytes + depth.nbytes  # the copies a push makes (depth as float32)

    def push(i):
        # fresh arrays each push, as a camera driver gives them
        stream.push(image.copy(), disparity, timestamp=float(i), T_w_c=np.eye(4), gt_depth=depth.copy())

    for i in range(5):
        push(i)
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i in range(5, 45):
        push(i)
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert grown < 4 * per_push, f"{grown / per_push:.1f} pushes' pixels kept after 40 pushes"
    inputs = StreamInputs()
    inputs.add_frame(seq[3])
    kept = inputs[0]
    assert (kept.index, kept.timestamp) == (3, seq[3].timestamp) and np.array_equal(kept.T_w_c, seq[3].T_w_c)
    with pytest.raises(InputError, match="not their images"):
        kept.image()
    assert kept.gt_depth() is None


def _same_result(a, b):
    assert (a.frame, a.status, a.reason) == (b.frame, b.status, b.reason)
    assert a.points.partners == b.points.partners
    np.testing.assert_array_equal(a.points.uv, b.points.uv)
    np.testing.assert_array_equal(a.points.depth, b.points.depth)
    if a.depth is None:
        assert b.depth is None
    else:
        assert (a.fit.alpha, a.fit.beta) == (b.fit.alpha, b.fit.beta)
        np.testing.assert_array_equal(a.depth, b.depth)


@pytest.mark.parametrize("prefetch", [0, 2])
def test_submitted_frames_give_what_pushed_frames_give(prefetch):
    """submit() processes in order in a background thread, features extracted ahead by the
    prefetch threads: the same results as push(), bit for bit, whatever the thread timing."""
    seq = open_sequence(STREET)
    disparity = create_disparity_source(DisparitySettings(), seq)
    inputs = [(seq[i].image(), disparity(seq[i]), seq[i].timestamp, seq[i].T_w_c) for i in range(7)]
    pushed = FrameStream(seq.camera)
    expected = [pushed.push(img, d, timestamp=t, T_w_c=T) for img, d, t, T in inputs]
    with FrameStream(seq.camera, prefetch=prefetch) as stream:
        assert stream.prefetch == prefetch
        futures = [stream.submit(img, d, timestamp=t, T_w_c=T) for img, d, t, T in inputs[:6]]
        last = stream.push(*inputs[6][:2], timestamp=inputs[6][2], T_w_c=inputs[6][3])  # after the queued ones
        got = [f.result() for f in futures] + [last]
    assert sum(r.depth is not None for r in expected) >= 2
    for a, b in zip(expected, got):
        _same_result(a, b)
    if prefetch:
        assert all(r.timings["features"] > 0 for r in got[:6])


def test_submit_checks_inputs_at_once_and_a_non_concurrent_matcher_gets_no_prefetch():
    seq = open_sequence(STREET)
    image = np.zeros((seq.camera.height, seq.camera.width, 3), np.uint8)
    with FrameStream(seq.camera, prefetch=2) as stream:
        stream.submit(image, None, timestamp=1.0)
        with pytest.raises(InputError, match="increase"):
            stream.submit(image, None, timestamp=1.0)
        with pytest.raises(InputError, match="expected"):
            stream.submit(image[:5], None, timestamp=2.0)
        assert stream.submit(image, None, timestamp=2.0).result().frame == 1  # refused inputs take no index
    with pytest.raises(InputError, match="prefetch"):
        FrameStream(seq.camera, prefetch=-1)
    no_matcher = FrameStream(seq.camera, PipelineSettings.from_presets(points="lidar:16"), prefetch=2)
    assert no_matcher.prefetch == 0


def test_submitted_frames_with_imu_samples_give_what_pushed_frames_give():
    """The IMU samples of a submitted frame reach the pose source in stream order, after the
    frames before it were processed: the imu source's results equal push()'s."""
    seq = open_sequence(ROOM)
    imu = seq.imu
    disparity = create_disparity_source(DisparitySettings(), seq)
    settings = PipelineSettings.from_presets(poses="imu", pairing="indoor")
    inputs, t_prev = [], -np.inf
    for i in range(0, 16, 2):
        frame = seq[i]
        new = (imu.t > t_prev) & (imu.t <= frame.timestamp + 0.02)
        t_prev = frame.timestamp + 0.02
        inputs.append((frame.image(), disparity(frame), dict(timestamp=frame.timestamp, T_w_c=frame.T_w_c,
                                                             imu=(imu.t[new], imu.gyro[new], imu.accel[new]))))
    pushed = FrameStream(seq.camera, settings, imu_calibration=imu)
    expected = [pushed.push(img, d, **kw) for img, d, kw in inputs]
    with FrameStream(seq.camera, settings, imu_calibration=imu, prefetch=2) as stream:
        got = [f.result() for f in [stream.submit(img, d, **kw) for img, d, kw in inputs]]
    assert any(r.points.partners for r in expected)
    for a, b in zip(expected, got):
        _same_result(a, b)
        assert (a.rescale is None) == (b.rescale is None)


def _room_vio_pushes(n: int):
    """The first ``n`` frames of the room sample as pushes with the IMU samples since the
    previous push (SIMULATED images, IMU and true inverse depth as the disparity)."""
    seq = open_sequence(ROOM)
    imu = seq.imu
    pushes, t_prev = [], -np.inf
    for i in range(n):
        frame = seq[i]
        new = (imu.t > t_prev) & (imu.t <= frame.timestamp)
        t_prev = frame.timestamp
        depth = frame.gt_depth()
        pushes.append((frame.image(), np.where(depth > 0, 1.0 / np.maximum(depth, 1e-6), 0.0).astype(np.float32),
                       dict(timestamp=frame.timestamp, imu=(imu.t[new], imu.gyro[new], imu.accel[new]))))
    return seq, pushes


@pytest.mark.parametrize("matcher", ["klt"])
def test_a_long_vio_stream_forgets_the_samples_and_frames_the_odometry_no_longer_reads(matcher, monkeypatch):
    """Memory of a ``--poses vio`` stream is flat in the number of pushes: before, the stream
    kept every pushed IMU sample (twice: the pushed chunks and their join, re-joined at each
    push) and every frame's record, 1.5 KiB a frame at 20 Hz with a 200 Hz IMU
    (benchmarks/bench_stream_memory.py --poses vio). Forgetting what the odometry no longer
    reads changes no result, bit for bit."""
    seq, pushes = _room_vio_pushes(120)
    settings = PipelineSettings.from_presets(matcher=matcher, poses="vio", pairing="indoor", points="vio")

    def run():
        stream = FrameStream(seq.camera, settings, imu_calibration=seq.imu)
        return stream, [stream.push(img, d, **kw) for img, d, kw in pushes]

    stream, got = run()
    kept = stream._inputs
    t_end = pushes[-1][2]["timestamp"]
    assert len(kept) == 120 and kept[119].timestamp == t_end
    assert kept.imu.t[0] > t_end - 4.0 and len(kept.frames) < 80, (kept.imu.t[0], len(kept.frames))
    with pytest.raises(IndexError, match="not kept"):
        kept[0]
    assert sum(r.depth is not None for r in got) >= 60  # the odometry tracked: the test means something

    monkeypatch.setattr(StreamInputs, "forget_before", lambda self, t: None)  # the stream as it was
    full, expected = run()
    assert full._inputs.imu.t[0] == seq.imu.t[0]
    for a, b in zip(expected, got):
        _same_result(a, b)
        assert (a.frame_pose is None) == (b.frame_pose is None)
        if a.frame_pose is not None and a.frame_pose.T_w_c is not None:
            np.testing.assert_array_equal(a.frame_pose.T_w_c, b.frame_pose.T_w_c)


def test_stream_inputs_forget_frames_and_samples_before_a_time():
    seq = open_sequence(ROOM)
    inputs = StreamInputs("exact", seq.imu)
    inputs.add_imu(np.array([0.0, 0.1]), np.zeros((2, 3)), np.zeros((2, 3)))
    inputs.add_imu(np.arange(2, 10) / 10.0, np.ones((8, 3)), np.ones((8, 3)))
    np.testing.assert_allclose(inputs.imu.t, np.arange(10) / 10.0)
    for i in range(5):
        inputs.add_frame(replace(seq[0], index=i, timestamp=i / 4.0))
    inputs.forget_before(0.6)
    np.testing.assert_allclose(inputs.imu.t, np.arange(2, 10) / 10.0)  # 4 samples before 0.6 kept
    assert inputs.imu.gyro.base is None  # a copy: the forgotten samples are freed
    assert len(inputs) == 5 and inputs.first == 3 and inputs[3].timestamp == 0.75
    with pytest.raises(IndexError):
        inputs[2]
    uncalibrated = StreamInputs()
    uncalibrated.add_imu(np.array([0.0]), np.zeros((1, 3)), np.zeros((1, 3)))
    assert uncalibrated.imu is None  # nothing could read them: not kept


def test_close_stops_the_streams_worker_process_and_refuses_later_frames():
    """With the odometry's window in a worker (``vio_realtime``), closing the stream stops the
    worker then and there: before, it lived until the garbage collector reached the dropped
    stream's object cycles, a 40-90 ms pause inside whatever frame was being processed then
    (benchmarks/bench_realtime.py timed rows after other rows' leftovers)."""
    seq, pushes = _room_vio_pushes(4)
    settings = PipelineSettings.from_presets(poses="vio_realtime", pairing="indoor")
    stream = FrameStream(seq.camera, settings, imu_calibration=seq.imu)
    (worker,) = stream.workers
    assert worker.alive
    for img, d, kw in pushes[:3]:
        stream.push(img, d, **kw)
    stream.close()
    assert not worker.alive
    with pytest.raises(InputError, match="closed"):
        stream.push(pushes[3][0], pushes[3][1], **pushes[3][2])
    stream.close()  # twice: harmless
