"""RunExporter on synthetic frames: files per option, backfill replacement, frames without pose."""

import json

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_depth.export import (
    ExportSettings,
    PlySettings,
    PreviewSettings,
    RunExporter,
    depth_from_rgb,
    read_depth_npy,
    read_png_rgb,
)
from vio_depth.frame import Frame
from vio_depth.pipeline import FrameResult, FrameStatus, PointSourceSpec, PointsOutcome

plyfile = pytest.importorskip("plyfile")
CAM = Camera(32, 24, 30.0, 30.0, 15.5, 11.5)


class FakeSequence:
    has_gt_depth = True

    def __init__(self, frames):
        self.frames = frames

    def __getitem__(self, i):
        return self.frames[i]

    def __len__(self):
        return len(self.frames)


def _frame(i, pose=True):
    T = np.eye(4)
    T[0, 3] = float(i)  # the camera moves 1 m along world x per frame
    gt = np.full((24, 32), 2.0 + i, np.float32)
    return Frame(i, 0.1 * i, f"{i:06d}", CAM, T if pose else None,
                 load_image=lambda: np.full((24, 32, 3), 10 * i, np.uint8), load_gt_depth=lambda: gt)


def _result(i, depth_value, n_points=5):
    depth = np.full((24, 32), depth_value, np.float32)
    depth[0, 0] = np.nan
    uv = np.stack([np.arange(n_points) * 3.0 + 2, np.full(n_points, 10.0)], 1)
    return FrameResult(i, f"{i:06d}", 0.1 * i, FrameStatus.OK, "", PointSourceSpec(),
                       PointsOutcome(FrameStatus.OK), depth=depth, points_uv=uv,
                       points_depth=np.full(n_points, depth_value), points_sigma=np.full(n_points, 0.1),
                       points_inlier=np.arange(n_points) % 2 == 0)


def test_every_output_and_backfill_replacement(tmp_path):
    frames = [_frame(0), _frame(1), _frame(2, pose=False)]
    settings = ExportSettings(npy=True, preview=PreviewSettings(), ply=PlySettings(sparse=True, dense_stride=8),
                              thumbnails=True)
    ex = RunExporter(tmp_path, settings)
    ex.add_frame(frames[0], _result(0, 3.0, n_points=4))
    ex.add_frame(frames[1], _result(1, 5.0))
    ex.add_frame(frames[2], _result(2, 7.0))
    ex.add_frame(frames[0], _result(0, 2.0, n_points=3))  # the backfill replaces frame 0
    records = [{"frame": i, "stem": f"{i:06d}", "status": "ok", "abs_rel": a} for i, a in enumerate([0.1, 0.2, 0.3])]
    rep = ex.finish(FakeSequence(frames), records)

    assert np.array_equal(read_depth_npy(tmp_path / "depth_npy" / "000000.npy"), _result(0, 2.0).depth, equal_nan=True)
    assert rep.depth_range == (2.0, 7.0)
    legend = json.loads((tmp_path / "preview" / "legend.json").read_text())
    assert legend["depth_range_m"] == [2.0, 7.0]
    back = depth_from_rgb(read_png_rgb(tmp_path / "preview" / "000001.png"), 2.0, 7.0)
    assert np.isnan(back[0, 0]) and np.allclose(back[1:, 1:], 5.0, rtol=0.003)
    err = read_png_rgb(tmp_path / "error" / "000000.png")  # depth 2 vs gt 2: exact -> grey centre
    assert err[5, 5].tolist() == [221, 221, 221]
    merged = plyfile.PlyData.read(str(tmp_path / "ply" / "sparse_map.ply"))["vertex"].data
    assert merged["frame"].tolist() == [0] * 3 + [1] * 5  # frame 0's newest points; frame 2 has no pose
    assert np.allclose(merged["x"][merged["frame"] == 1] - 1.0,
                       (np.arange(5) * 3.0 + 2 - 15.5) / 30.0 * 5.0, atol=1e-5)  # moved by T_w_c
    assert merged["inlier"].tolist()[3:] == [1, 0, 1, 0, 1] and np.allclose(merged["sigma_depth"], 0.1)
    assert sorted(p.name for p in (tmp_path / "ply" / "dense").iterdir()) == ["000000.ply", "000001.ply"]
    assert rep.counts == {"depth_npy": 3, "previews": 3, "error_maps": 3, "ply_sparse_frames": 2,
                          "ply_sparse_map_points": 8, "ply_dense_frames": 2, "thumbnails": 3}
    assert any("without a camera-to-world pose" in n for n in rep.notes)
    assert sorted(p.name for p in (tmp_path / "thumbs").iterdir()) == sorted(
        [f"{i:06d}_{k}" for i in range(3) for k in ("image.jpg", "preview.png", "error.png")] + ["legend.json"])


def test_nothing_asked_nothing_written(tmp_path):
    ex = RunExporter(tmp_path / "o", ExportSettings())
    ex.add_frame(_frame(0), _result(0, 3.0))
    assert ex.finish(FakeSequence([_frame(0)]), []).counts == {}
    assert not (tmp_path / "o").exists()
