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


def test_the_ate_is_the_aligned_rmse_of_the_live_positions():
    """A trajectory moved and turned rigidly has ATE 0; a 3 cm error on one of four frames gives
    its RMSE after the alignment (the alignment spreads part of it: below 3 / 2 cm)."""
    ds = _room_gt(4)
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    truth = np.stack([np.eye(4)] * 4)
    truth[:, :3, 3] = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.5]]
    runner = br.StreamRunner(replace(ds, truth_T_w_c=truth))
    assert runner.ate_m() is None  # nothing posed yet
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix(), [5, -2, 1]
    runner.estimates = {i: M @ truth[i] for i in range(4)}
    assert runner.ate_m() == pytest.approx(0.0, abs=1e-12)
    runner.estimates[2] = runner.estimates[2] @ np.array([[1, 0, 0, 0.03], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    assert 0.005 < runner.ate_m() < 0.015


def _vio_row(default: bool, ate_m: float, abs_rel: float, matcher: str = "sift") -> br.Row:
    replay = br.Replay(np.zeros(3), afap=True)
    return br.Row("asl", "752x564", "vio", "afap", 3, replay, 3, ate_m=ate_m, abs_rel=abs_rel, default=default,
                  matcher=matcher)


def test_a_fast_configuration_is_judged_against_the_reference_row_of_the_same_run():
    base = _vio_row(True, 0.010, 0.020)
    text, held = br.accuracy_against_default(_vio_row(False, 0.0109, 0.0209, "klt"), [base])
    assert held and "ATE 1.09 x the reference's 10.0 mm (within +10%)" in text
    text, held = br.accuracy_against_default(_vio_row(False, 0.0112, 0.0200, "klt"), [base])
    assert not held and "beyond +10%" in text
    text, held = br.accuracy_against_default(_vio_row(False, 0.0100, 0.0212, "klt"), [base])
    assert not held and "AbsRel 1.06 x" in text and "beyond +5%" in text
    text, held = br.accuracy_against_default(_vio_row(False, 0.0100, 0.0212, "klt"), [])
    assert held and "no reference row" in text


def test_vio_set_replaces_odometry_and_window_fields_and_refuses_others():
    """``--vio-set``: fields of VioSettings and of its window, values as Python literals; an unknown
    field, ``window``/``backend`` themselves or a value that is not a literal is an error."""
    changes = br.parse_window("solver='isam2'; bridge_every_update=False;ba_max_landmarks=400")
    assert changes == {"solver": "isam2", "bridge_every_update": False, "ba_max_landmarks": 400}
    assert br.parse_window("") == {}
    for bad in ("foo=1", "backend='process'", "solver=isam2", "solver"):
        with pytest.raises(ValueError, match="--vio-set"):
            br.parse_window(bad)


def test_a_row_without_depth_is_not_judged():
    """A sequence whose frames never got depth (the EuRoC slice: the camera is still) holds any rate
    trivially: its verdict says so instead of PASS."""
    fast = _vio_row(False, 0.004, 0.002, "klt")
    fast.replay = br.Replay(np.zeros(3), processed=[0, 1, 2], starts=[0.0, 0.01, 0.02], finishes=[0.01, 0.02, 0.03],
                            afap=True)
    assert br.verdicts([fast])[0].endswith("**PASS**")
    fast.with_depth = 0
    assert br.verdicts([fast])[0].endswith("**NOT JUDGED**")


def test_a_preloaded_runner_scores_the_same_depth_after_the_replay():
    """Rows with the window's worker decode every frame beforehand and score the depth after the
    replay (decoding and scoring in its wall time would slow the pushes and feed the worker): the
    AbsRel is the one scored frame by frame."""
    from dataclasses import replace

    ds = replace(_room_gt(6), true_depth=lambda d: np.where(d > 0, 1.0 / np.maximum(d, 1e-6), 0.0))
    inline, preloaded = br.StreamRunner(ds, matcher="sift"), br.StreamRunner(ds, matcher="sift")
    preloaded.preload()
    for i in range(len(ds)):
        inline(i)
        preloaded(i)
    assert inline.abs_rel and preloaded.abs_rel == [] and preloaded.held_mib() > 0
    preloaded.score_deferred()
    assert preloaded.abs_rel == pytest.approx(inline.abs_rel)


def _spiky_row(spikes: dict[int, float]) -> br.Row:
    """200 frames at 20 Hz through the replay's queue (one waiting frame), each taking 10 ms but
    ``spikes`` ({frame: seconds}); frame 3 is the first posed one."""
    replay = br.replay(np.arange(200) * 0.05, lambda i: spikes.get(i, 0.01), rate_scale=1.0, queue_size=1)
    return br.Row("asl", "752x564", "vio", "realtime x1", 200, replay, 150, matcher="klt",
                  posed=[i >= 3 for i in replay.processed])


def test_drops_after_the_start_exclude_the_frames_that_arrived_before_the_first_pose_was_out():
    """The first posed frame (3) takes 0.3 s (the start taken over from the worker): frames 4-9
    arrive meanwhile, 4-8 are dropped -- the start's, not counted after it; a 0.2 s frame later
    (100) drops 101-103 after the start and fails the verdict."""
    fast = _vio_row(False, 0.004, 0.002, "klt")
    fast.replay = br.Replay(np.zeros(3), processed=[0, 1, 2], starts=[0.0, 0.01, 0.02], finishes=[0.01, 0.02, 0.03],
                            afap=True)
    start_only = _spiky_row({3: 0.3})
    assert start_only.replay.dropped == [4, 5, 6, 7, 8] and start_only.steady_dropped() == 0
    verdict = br.verdicts([fast, start_only])[0]
    assert "5 of 200 frames dropped (0 after the start)" in verdict and verdict.endswith("**PASS**")
    later = _spiky_row({3: 0.3, 100: 0.2})
    assert later.replay.dropped == [4, 5, 6, 7, 8, 101, 102, 103] and later.steady_dropped() == 3
    verdict = br.verdicts([fast, later])[0]
    assert "8 of 200 frames dropped (3 after the start)" in verdict and verdict.endswith("**FAIL**")
    after = br.HEADER.index("dropped after start")
    assert later.cells()[after] == "3" and fast.cells()[after] == "-"


def test_pose_presets_must_be_the_odometry_presets():
    """``--pose-presets`` names the CLI's vio presets; gt (or a typo) is refused with the valid names."""
    for bad in ("gt", "vio_fast"):
        with pytest.raises(SystemExit):
            br.main(["--datasets", "asl_room", "--pose-presets", bad])


def test_preset_rows_take_the_presets_matcher_and_points_unless_named():
    """A ``--pose-presets`` row is built as ``vio-depth run --poses NAME`` builds it: vio_offline with
    sift and two-view points, vio with klt and the odometry's own landmarks; ``--vio-points``
    names the points for every preset instead."""
    rows = br.preset_specs(["vio_offline", "vio"], [], ["afap"])
    assert rows == [("sift", "sfm", "afap", "vio_offline"), ("klt", "vio", "afap", "vio")]
    named = br.preset_specs(["vio_realtime"], ["sfm", "vio"], ["afap"])
    assert [r[1] for r in named] == ["sfm", "vio"]
