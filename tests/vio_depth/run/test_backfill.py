"""When the offline run replays its frames forwards before the backward pass
(vio_depth/run/backfill.py: ``replay_posed_late``): only when no frame had depth, some had no pose
and the pose source tracks (the odometry, whose worker may pose frames only at the sequence's end);
the run-level behaviour is tests/vio_depth/vio/test_vio_runs.py's short-clip test."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from vio_depth.pipeline import FrameStatus
from vio_depth.run import backfill

N = 6


def _results(statuses, depth_at=()):
    return {i: SimpleNamespace(status=s, has_depth=i in depth_at) for i, s in enumerate(statuses)}


@pytest.fixture
def calls(monkeypatch):
    seen = []

    def fake_replay(sequence, pipeline, order, wanted, **kwargs):
        seen.append((list(order), set(wanted)))
        return {i: ("frame", "result") for i in wanted if i >= 2}

    monkeypatch.setattr(backfill, "_replay", fake_replay)
    return seen


def test_a_tracking_source_s_run_without_depth_is_replayed_forwards(calls):
    res = _results([FrameStatus.NO_POSE] * N)
    out = backfill.replay_posed_late(None, SimpleNamespace(tracker=object()), res, N)
    assert calls == [(list(range(N)), set(range(N)))]
    assert sorted(out) == [2, 3, 4, 5]


@pytest.mark.parametrize("case", ["no tracker", "a frame had depth", "every frame had a pose"])
def test_no_replay_otherwise(calls, case):
    tracker = None if case == "no tracker" else object()
    statuses = [FrameStatus.NO_PAIR if case == "every frame had a pose" else FrameStatus.NO_POSE] * N
    res = _results(statuses, depth_at=(4,) if case == "a frame had depth" else ())
    assert backfill.replay_posed_late(None, SimpleNamespace(tracker=tracker), res, N) == {}
    assert calls == []
