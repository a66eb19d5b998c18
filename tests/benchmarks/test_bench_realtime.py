"""benchmarks/bench_realtime.py's measurement code on a few frames of the room sample (its
datasets are rendered or real and too slow for the suite; the benchmark itself is run by hand)."""

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_realtime as br  # noqa: E402
import realtime_data as data  # noqa: E402
from vio_depth.io import open_sequence  # noqa: E402

ROOM = ROOT / "sample_sequences" / "room"


def _room_gt(n: int) -> data.StreamData:
    """The first ``n`` frames of the room sample with its exact poses and the true inverse depth
    as the disparity (SIMULATED, like the sample)."""
    seq = open_sequence(ROOM)
    frames = [seq[i] for i in range(n)]

    def load(i):
        depth = frames[i].gt_depth()
        return frames[i].image(), np.where(depth > 0, 1.0 / np.maximum(depth, 1e-6), 0.0).astype(np.float32)

    return data.StreamData("room", "room sample (SIMULATED)", seq.camera, np.array([f.timestamp for f in frames]),
                           load, "gt", "indoor", T_w_c=np.stack([f.T_w_c for f in frames]))


@pytest.mark.parametrize("rate_scale", [None, 50.0])
def test_a_gt_row_has_every_frame_posed_and_a_latency_after_the_start(rate_scale):
    """A row of given poses: every frame is posed (no tracking source: ``frame_pose`` is None), so
    the p99 after the start is the p99 over all frames but the first. Before, recording a frame read a
    ``FrameResult.T_w_c`` that does not exist and every pipeline row raised AttributeError."""
    row = br.pipeline_row(_room_gt(5), rate_scale, queue_size=5, warmup=0, matcher="sift")
    assert row.frames == 5 and row.posed == [True] * len(row.replay.processed)
    lat = 1000 * row.replay.latencies
    assert row.steady_p99_ms() == pytest.approx(np.percentile(lat[1:], 99))
    assert sum(row.statuses.values()) == len(row.replay.processed) and row.with_depth >= 1
