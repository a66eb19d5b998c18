"""The landmark points stage in the pipeline: metric points from the window, records, errors."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from vio_depth import Pipeline, PipelineSettings, open_sequence
from vio_depth.pipeline import FrameStatus
from vio_depth.run import RunSettings, read_frames_jsonl, run_sequence

STREET = Path(__file__).resolve().parents[3] / "sample_sequences" / "street"
ROOM = STREET.parent / "room"
pytestmark = pytest.mark.skipif(not (STREET / "sequence.json").exists(), reason="bundled samples missing")


def test_landmark_points_are_metric_and_the_window_poses_are_used(tmp_path):
    seq = open_sequence(STREET)
    assert seq.pose_kind == "exact"  # rendered: the tightest pose prior
    settings = PipelineSettings.from_presets(points="landmarks")
    run_sequence(seq, Pipeline(settings, sequence=seq), tmp_path / "out", RunSettings(max_frames=12))
    _, frames = read_frames_jsonl(tmp_path / "out" / "frames.jsonl")
    # (frame 0's record comes from the backward pass, where it is the last frame: a keyframe
    # only when it has enough parallax with the window's newest one)
    assert all(f["point_source"] == "landmarks" for f in frames)
    with_depth = [f for f in frames if f["alpha"] is not None]
    assert len(with_depth) >= 11  # the first frame only through the backward pass
    assert sum(f.get("keyframe", False) for f in frames) >= 3
    for f in with_depth[1:]:
        assert f["points_rel_err_median"] < 0.03 and f["abs_rel"] < 0.05
    # trajectory.tum holds the window's poses: within millimetres of the exact ones
    rows = np.loadtxt(tmp_path / "out" / "trajectory.tum")
    assert len(rows) >= 11
    truth = {round(seq[i].timestamp, 6): seq[i].T_w_c[:3, 3] for i in range(12)}
    err = [np.linalg.norm(r[1:4] - truth[round(r[0], 6)]) for r in rows]
    assert max(err) < 0.01


def test_a_frame_without_a_pose_gets_no_pose_not_an_exception():
    seq = open_sequence(STREET)
    pipe = Pipeline(PipelineSettings.from_presets(points="landmarks"), sequence=seq)
    pipe.process(seq[0])
    frame = seq[1]
    frame.T_w_c = None
    res = pipe.process(frame)
    assert res.status == FrameStatus.NO_POSE and res.depth is None


def test_the_window_in_a_worker_process_gives_the_frames_depth_as_the_inline_one_does(tmp_path):
    """``[landmarks_backend] kind = "process"``: keyframe updates run in a worker and are taken
    over ``lag_frames`` later; the frames meanwhile are answered from the window as it was, so the
    run is not the inline one bit for bit, but as metric and as complete (exact street poses)."""
    seq = open_sequence(STREET)
    runs = {}
    for kind in ("inline", "process"):
        settings = PipelineSettings.from_dict({"landmarks_backend": {"kind": kind}},
                                              PipelineSettings.from_presets(points="landmarks"))
        pipe = Pipeline(settings, sequence=seq)
        assert pipe.points.estimator.in_worker == (kind == "process")
        assert pipe.points.estimator.backend_settings.lag_frames == 2  # the points window's default
        run_sequence(seq, pipe, tmp_path / kind, RunSettings(max_frames=16, backfill=False))
        # the offline backward pass's pipeline keeps its window here: a worker would only add its start
        assert not pipe.fresh(inline_window=True).points.estimator.in_worker
        runs[kind] = read_frames_jsonl(tmp_path / kind / "frames.jsonl")[1]
    inline, worker = runs["inline"], runs["process"]
    # the window's first two keyframes are inserted as inline (they start its landmarks), later
    # ones are submitted to the worker: chosen (a reason) but not yet in the window (keyframe false)
    chosen = [f["frame"] for f in worker if f.get("keyframe_reason")]
    inserted = [f["frame"] for f in worker if f.get("keyframe")]
    assert inserted[0] == 0 and len(inserted) == 2 and inserted[1] in chosen  # (frame 0 needs no reason)
    assert len(chosen) >= 3
    depth_inline = [f["frame"] for f in inline if f["alpha"] is not None]
    depth_worker = [f["frame"] for f in worker if f["alpha"] is not None]
    assert len(depth_worker) >= len(depth_inline) - 1
    for f in worker:
        if f["alpha"] is not None:
            assert f["points_rel_err_median"] < 0.03 and f["abs_rel"] < 0.05
    assert np.mean([f["abs_rel"] for f in worker if f["alpha"] is not None]) < \
        1.1 * np.mean([f["abs_rel"] for f in inline if f["alpha"] is not None])


def test_close_stops_the_workers_the_pipeline_started_and_no_other():
    """Pipeline.close stops its points window's worker; a pipeline made by ``fresh`` (the
    offline backward pass) shares its maker's pose stage and stops none of its workers."""
    seq = open_sequence(STREET)
    base = PipelineSettings.from_presets(points="landmarks")
    settings = replace(base, landmarks_backend=replace(base.landmarks_backend, kind="process"))
    with Pipeline(settings, sequence=seq) as pipe:
        (worker,) = pipe.workers
        assert worker.alive
        backward = pipe.fresh(inline_window=True)
        assert backward.workers == ()
        backward.close()
        assert worker.alive
    assert not worker.alive

    room = open_sequence(ROOM)
    pipe = Pipeline(PipelineSettings.from_presets(poses="vio_realtime", pairing="indoor"), sequence=room)
    (odometry_worker,) = pipe.workers
    pipe.fresh().close()
    assert odometry_worker.alive
    pipe.close()
    assert not odometry_worker.alive
