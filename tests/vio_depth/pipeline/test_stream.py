"""FrameStream: pushing arrays gives exactly what the pipeline gives on the same frames."""

from pathlib import Path

import numpy as np
import pytest

from vio_core import InputError, ShapeError
from vio_depth import FrameStream, Pipeline, PipelineSettings, open_sequence
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.pipeline import FrameStatus

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
