"""Triangulated SIFT points against real ground truth (kitti_tiny, 7scenes_redkitchen).

Skips without ../shared/data or without the SIFT matcher / triangulation modules. Uses the
default settings of both (nothing tuned per dataset); pairs come from the sequences'
own poses.
"""

from pathlib import Path

import numpy as np
import pytest

from matchers import create_matcher
from vio_core.geometry import relative_transform
from vio_depth.evaluation.point_accuracy import point_depth_errors

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def tools():
    tri = pytest.importorskip("triangulation")
    return create_matcher("sift"), tri.triangulate_pair, tri.TriangulationSettings()


def _open(name):
    if not (DATA / name).is_dir():
        pytest.skip(f"{DATA / name} not present")
    from vio_depth.io import open_sequence

    return open_sequence(DATA / name)


def _evaluate(seq, pairs, tools):
    """Triangulate each (keyframe, current) pair; per-pair (valid points, PointAccuracy, rel. errors)."""
    matcher, triangulate_pair, settings = tools
    feats, out = {}, []
    for a, b in pairs:
        for i in (a, b):
            if i not in feats:
                feats[i] = matcher.extract(seq[i].image())
        kf, cur = seq[a], seq[b]
        m = matcher.match(feats[b], feats[a])
        pts = triangulate_pair(feats[b].keypoints[m.idx_a], feats[a].keypoints[m.idx_b], cur.camera, kf.camera,
                               relative_transform(kf.T_w_c, cur.T_w_c), settings, confidence=m.confidence)
        v = pts.valid
        acc = point_depth_errors(pts.uv[v], pts.depth[v], cur.gt_depth())
        ev = acc.evaluated
        rel = np.abs(pts.depth[v][ev] - acc.gt_depth[ev]) / acc.gt_depth[ev]
        out.append((int(v.sum()), acc, rel))
        print(f"{seq.name} {a}->{b}: valid {int(v.sum())}, evaluated {acc.count}, "
              f"median {acc.median:.2%}, p90 {acc.p90:.2%}, bias {acc.bias:+.2%}")
    return out


def test_kitti_tiny_sift_points_against_lidar(tools):
    seq = _open("kitti_tiny")
    results = _evaluate(seq, [(k, k + 1) for k in range(len(seq) - 1)], tools)
    # measured: 336-406 valid points, 230-301 with LiDAR in their 5x5 window, medians 1.5-2.6 %
    for n_valid, acc, _ in results:
        assert n_valid >= 200
        assert acc.count >= 100
        assert acc.median <= 0.05


def test_7scenes_sift_points_against_kinect_depth(tools):
    seq = _open("7scenes_redkitchen")
    # hand-held, <= 3.6 cm between frames: pair frames 20 apart (~0.1-0.2 m baselines)
    results = _evaluate(seq, [(a, a + 20) for a in range(0, len(seq) - 20, 20)], tools)
    pooled = np.concatenate([rel for _, _, rel in results])
    per_frame = [acc.median for _, acc, _ in results if acc.count]
    print(f"7scenes pooled median {np.median(pooled):.2%} over {len(pooled)} points; "
          f"median of per-frame medians {np.median(per_frame):.2%}")
    # all points of all pairs: measured 4.2 %; the middle of the sequence (fast hand-held
    # motion, colour/depth not synchronised) has single pairs far worse, see docs/datasets.md
    assert len(pooled) >= 1000
    assert np.median(pooled) <= 0.05
