"""The dynamic initialisation attempt in the window's worker process (``VioSettings.backend``
kind ``process``, vio_depth/vio/init_remote.py) on a synthetic scene of known truth: the frame
that completes the candidates submits the attempt and returns without its outcome, which is
taken over ``init_lag_frames`` later with the synchronous start's keyframes and states; the
frames offered meanwhile keep initialising and are posed afterwards; a refused attempt is
handled as in the frame; ``init_lag_frames`` 0 is the synchronous start (test_window_worker.py
compares it with the inline run bit for bit)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vio_depth.evaluation import CameraTrajectory, absolute_trajectory_error
from vio_depth.landmarks import WindowBackendSettings
from vio_depth.pipeline import POSE_PRESETS
from vio_depth.vio import InitKind, VioEstimator, VioSettings, VioStatus

from .synthetic import IdMatcher, make_scene

pytest.importorskip("gtsam")

SETTINGS: VioSettings = POSE_PRESETS["vio"]


@pytest.fixture(scope="module")
def scene():
    return make_scene(duration_s=4.0, seed=1)


def _run(scene, backend: WindowBackendSettings, settings: VioSettings = SETTINGS, frames: int | None = None):
    est = VioEstimator(scene.imu, IdMatcher(), replace(settings, backend=backend))
    out, flight = [], []
    for k, f in enumerate(scene.frames[:frames]):
        out.append(est.process(f.index, f.timestamp, f.camera, scene.features[k]))
        flight.append(est.backend is not None and est._init.in_flight)
    nan = np.full((4, 4), np.nan)
    poses = np.stack([nan if est.history.pose(i) is None else est.history.pose(i) for i in range(len(out))])
    if est.backend is not None:
        est.backend.close()
    return est, out, poses, flight


@pytest.fixture(scope="module")
def inline(scene):
    return _run(scene, WindowBackendSettings("inline"))


def test_the_attempt_is_taken_over_init_lag_frames_later_with_the_synchronous_start(scene, inline):
    est_inline, out_inline, _, _ = inline
    start = next(i for i, o in enumerate(out_inline) if o.ok)  # the synchronous start's frame
    assert out_inline[start].initialised == InitKind.DYNAMIC
    lag = 5
    est, out, poses, flight = _run(scene, WindowBackendSettings("process", lag_frames=1, start_lag_frames=0,
                                                                init_lag_frames=lag))
    # the frame that completed the candidates submitted the attempt and returned without its outcome
    assert flight[start] and not flight[start - 1] and est._init.submitted == 1
    assert all(flight[start: start + lag]) and not flight[start + lag]
    assert [o.status for o in out[: start + lag]] == [VioStatus.INITIALISING] * (start + lag)
    landed = out[start + lag]
    assert landed.ok and landed.initialised == InitKind.DYNAMIC and not landed.keyframe
    # the synchronous start's keyframes and states (the same computation, in the worker)
    a, b = est.last_init, est_inline.last_init
    assert [k.frame_id for k in a.keyframes] == [k.frame_id for k in b.keyframes]
    for sa, sb in zip(a.states, b.states):
        np.testing.assert_allclose(sa.T_w_i, sb.T_w_i, rtol=0, atol=1e-9)
        np.testing.assert_allclose(sa.velocity_w, sb.velocity_w, rtol=0, atol=1e-9)
        np.testing.assert_allclose(sa.gyro_bias, sb.gyro_bias, rtol=0, atol=1e-12)
    assert a.alignment.scale == pytest.approx(b.alignment.scale, rel=1e-9)
    # the frames offered while it ran are posed after the start (bridged between its newest
    # keyframe and the next one), and every frame after the start is tracked
    ran = [scene.frames[k].index for k in range(start + 1, start + lag)]
    assert {f for f, _ in a.frames} >= set(ran)
    assert all(est.history.pose(f) is not None for f in ran)
    assert all(o.ok for o in out[start + lag:])
    posed = np.flatnonzero(np.isfinite(poses[:, 0, 0]))
    assert len(posed) == len(b.keyframes) + len(a.frames) + len(out) - start - lag
    t = np.array([scene.frames[k].timestamp for k in posed])
    ate = absolute_trajectory_error(CameraTrajectory(t, poses[posed]), CameraTrajectory(t, scene.T_w_c[posed]))
    assert ate.rmse < 0.005 * scene.path_length() and abs(ate.scale - 1) < 0.01, (ate.rmse, ate.scale)


def test_with_the_start_built_in_the_worker_too_its_lag_counts_from_the_attempt_s_frame(scene):
    """``start_lag_frames`` counts from the frame that submitted the attempt: the first tracked
    frame and every pose are those of the run with the attempt in its own frame, reproducibly; the
    frames that waited for the attempt or for the start's window are posed afterwards in both."""
    start_lag, init_lag = 8, 5
    est0, out0, poses0, _ = _run(scene, WindowBackendSettings("process", lag_frames=4, start_lag_frames=start_lag,
                                                              init_lag_frames=0))
    backend = WindowBackendSettings("process", lag_frames=4, start_lag_frames=start_lag, init_lag_frames=init_lag)
    est, out, poses, flight = _run(scene, backend)
    _, out2, poses2, _ = _run(scene, backend)
    np.testing.assert_array_equal(poses, poses2)
    assert [o.status for o in out] == [o.status for o in out2]
    submitted = flight.index(True)
    landed = next(i for i, o in enumerate(out) if o.initialised is not None)
    assert landed == submitted + start_lag == next(i for i, o in enumerate(out0) if o.initialised is not None)
    assert all(o.status == VioStatus.INITIALISING for o in out[:landed])
    assert "the window is being built" in out[submitted + init_lag].reason
    assert est.last_init.keyframes[-1].frame_id == est0.last_init.keyframes[-1].frame_id == scene.frames[submitted].index
    assert [o.status for o in out] == [o.status for o in out0]
    both = np.isfinite(poses0[:, 0, 0])
    np.testing.assert_allclose(poses[both], poses0[both], rtol=0, atol=1e-9)
    assert all(both[k] for k in range(submitted + 1, landed))


def test_a_refused_attempt_keeps_the_candidates_and_the_next_one_is_submitted(scene):
    """An alignment that cannot be trusted (here: a scale 1-sigma bound nothing meets) is
    refused in the worker as in the frame: the candidates stay, the reason is reported on the
    next frames, and a new attempt goes out once the refusal is in."""
    settings = replace(SETTINGS, init=replace(SETTINGS.init, max_scale_sigma=1e-9))
    n = 60
    _, out_inline, _, _ = _run(scene, WindowBackendSettings("inline"), settings, frames=n)
    lag = 3
    est, out, _, flight = _run(scene, WindowBackendSettings("process", init_lag_frames=lag), settings, frames=n)
    assert not any(o.ok for o in out) and not any(o.ok for o in out_inline)
    refused = [o.reason for o in out_inline if "dynamic initialisation refused" in o.reason]
    assert refused and all("too little excitation" in r for r in refused)
    first = flight.index(True)
    assert "last attempt" not in out[first + lag - 1].reason
    assert "last attempt: dynamic initialisation refused" in out[first + lag].reason
    assert "too little excitation" in out[first + lag].reason
    assert est._init.submitted >= 3
    # an alignment's refusal does not drop the oldest candidate (as inline)
    assert est.initializer.candidates()[0].frame_id == 0


def test_candidates_collected_while_the_attempt_ran_join_the_start_s_window(scene):
    """``catch_up_keyframes``: the candidates the initialisation collected after the attempt's
    newest keyframe (while it ran in the worker) join the start's window after its keyframes,
    spread evenly up to the newest, so the first keyframe tracked is not matched across both
    lags; 0 leaves the gap. Every frame is posed either way, and the trajectory holds."""
    runs = {}
    for n in (0, 2):
        backend = WindowBackendSettings("process", lag_frames=4, start_lag_frames=20, init_lag_frames=10,
                                        catch_up_keyframes=n)
        runs[n] = _run(scene, backend)
    est0, out0, poses0, _ = runs[0]
    est2, out2, poses2, _ = runs[2]
    newest = est2.last_init.keyframes[-1].frame_id
    first = next(i for i, o in enumerate(out2) if o.initialised is not None)
    assert first == next(i for i, o in enumerate(out0) if o.initialised is not None)
    first_id = scene.frames[first].index
    assert est0._catch_up == [] and len(est2._catch_up) == 2
    caught = [c.frame_id for c in est2._catch_up]
    assert newest < caught[0] < caught[1] < first_id
    # spread evenly: the first about half-way in time between the attempt's newest and the last
    t0, (ta, tb) = est2.last_init.keyframes[-1].t, [c.t for c in est2._catch_up]
    assert 0.25 < (ta - t0) / (tb - t0) < 0.75
    ids0, ids2 = est0.landmarks.window.keyframe_ids, est2.landmarks.window.keyframe_ids
    assert not set(caught) & set(ids0) and set(caught) <= set(ids2)
    # nothing tracked before the start's take-over, everything after it
    for out, poses in ((out0, poses0), (out2, poses2)):
        assert all(o.status == VioStatus.INITIALISING for o in out[:first]) and all(o.ok for o in out[first:])
        posed = np.flatnonzero(np.isfinite(poses[:, 0, 0]))
        assert set(range(first, len(out))) <= set(posed)
        t = np.array([scene.frames[k].timestamp for k in posed])
        ate = absolute_trajectory_error(CameraTrajectory(t, poses[posed]), CameraTrajectory(t, scene.T_w_c[posed]))
        assert ate.rmse < 0.005 * scene.path_length() and abs(ate.scale - 1) < 0.01, (ate.rmse, ate.scale)
