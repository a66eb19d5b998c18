"""`vio-depth run --report` with every export on 12 frames of the bundled room sample
(SIMULATED disparity): each format is read back and checked against the run's own numbers."""

import importlib.util
import json
import shutil
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")
plyfile = pytest.importorskip("plyfile")

from vio_core.geometry import invert_transform, transform_points
from vio_depth.cli import main
from vio_depth.export import colormap_lut, depth_from_rgb, nearest_index, read_depth_npy, read_png_rgb
from vio_depth.io import open_sequence
from vio_depth.io.depth_png import read_depth_png
from vio_depth.run import read_frames_jsonl

ROOT = Path(__file__).resolve().parents[3]
ROOM = ROOT / "sample_sequences" / "room"
_spec = importlib.util.spec_from_file_location("report_links", Path(__file__).with_name("report_links.py"))
report_links = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(report_links)

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not (ROOM / "sequence.json").exists(), reason="bundled room sample missing")]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("e2e") / "room"
    rc = main(["run", str(ROOM), "--out", str(out), "--pairing", "indoor", "--max-depth", "10", "--max-frames", "12",
               "--no-progress", "--save-npy", "--save-preview", "--save-ply", "sparse,dense:8", "--ply-frames", "3,5",
               "--report"])
    assert rc == 0
    return out


def _records(out):
    return read_frames_jsonl(out / "frames.jsonl")[1]


def test_report_has_its_sections_and_links_resolve_after_moving(run_dir, tmp_path):
    html = (run_dir / "report" / "index.html").read_text()
    for title in ("Run", "Summary", "Scale over time", "Points and inliers", "Status timeline",
                  "Accuracy against ground truth", "Best, median and worst frames"):
        assert f">{title}</h2>" in html
    for img in ("plots/scale.png", "plots/points.png", "plots/status.png", "plots/dense_error.png",
                "plots/point_accuracy.png"):
        assert f'src="{img}"' in html
    installed = version("vio-depth")
    assert "--save-preview" in html and f"<td>{installed}</td>" in html and '"preset": "klt"' in html  # the default with gt poses
    assert "SIMULATED" in html and "Omitted" not in html
    assert html.count("_image.jpg") == 3 and html.count("thumbs/0") == 9 and html.count("_preview.png") == 3
    for page in (run_dir / "report" / "index.html", run_dir / "report" / "report.md"):
        assert report_links.broken_links(page) == [] and report_links.no_network(page)
    moved = tmp_path / "other_machine"
    shutil.copytree(run_dir, moved)
    for page in (moved / "report" / "index.html", moved / "report" / "report.md"):
        assert report_links.broken_links(page) == []


def test_npy_matches_the_png_and_preview_colours_invert_to_the_depth(run_dir):
    recs = [r for r in _records(run_dir) if r["status"] == "ok"]
    assert len(recs) == 12
    legend = json.loads((run_dir / "preview" / "legend.json").read_text())
    lo, hi = legend["depth_range_m"]
    assert 0.3 < lo < hi < 10  # the room is 0.5-6.8 m deep
    stem = recs[5]["stem"]
    depth = read_depth_npy(run_dir / "depth_npy" / f"{stem}.npy")
    png = read_depth_png(run_dir / "depth" / f"{stem}.png")
    valid = np.isfinite(depth)
    assert np.array_equal(valid, png > 0)
    assert np.max(np.abs(depth[valid] - png[valid])) <= 0.5 / 256 + 1e-6  # PNG quantisation only
    rgb = read_png_rgb(run_dir / "preview" / f"{stem}.png")
    assert rgb.shape == depth.shape + (3,)
    back = depth_from_rgb(rgb, lo, hi, legend["colormap"], legend["scale"])
    inside = valid & (depth > lo) & (depth < hi)
    assert inside.mean() > 0.9
    half_step = np.log(hi / lo) / 255 / 2
    assert np.max(np.abs(np.log(back[inside] / depth[inside]))) <= half_step + 1e-5


def test_error_map_colours_are_the_relative_error_against_ground_truth(run_dir):
    seq = open_sequence(ROOM)
    rec = _records(run_dir)[7]
    depth = read_depth_npy(run_dir / "depth_npy" / f"{rec['stem']}.npy")
    gt = seq[rec["frame"]].gt_depth()
    err = (depth - gt) / gt
    rgb = read_png_rgb(run_dir / "error" / f"{rec['stem']}.png")
    shown = (nearest_index(rgb, colormap_lut("coolwarm")) / 254.0) * 0.4 - 0.2  # 255 levels over +-20 %
    ok = np.isfinite(err) & (np.abs(err) < 0.19)
    assert np.max(np.abs(shown[ok] - err[ok])) <= 0.4 / 254 / 2 + 1e-6
    assert np.median(np.abs(err[ok])) == pytest.approx(rec["abs_rel"], rel=0.5)


def test_sparse_clouds_hold_the_frames_points_in_the_world_frame(run_dir):
    seq = open_sequence(ROOM)
    recs = _records(run_dir)
    total = 0
    for rec in recs:
        v = plyfile.PlyData.read(str(run_dir / "ply" / "sparse" / f"{rec['stem']}.ply"))["vertex"].data
        assert len(v) == rec["points_sampled"] and np.all(v["frame"] == rec["frame"])
        assert int(v["inlier"].sum()) == rec["fit_diagnostics"]["n_inliers"]
        assert np.all(v["sigma_depth"] > 0)
        total += len(v)
    merged = plyfile.PlyData.read(str(run_dir / "ply" / "sparse_map.ply"))["vertex"].data
    assert len(merged) == total and sorted(set(merged["frame"].tolist())) == list(range(12))
    # frame 4's points, moved back into its camera, sit on the ground-truth surface
    frame = seq[4]
    mine = merged[merged["frame"] == 4]
    p_c = transform_points(invert_transform(frame.T_w_c), np.stack([mine["x"], mine["y"], mine["z"]], 1))
    assert np.allclose(p_c[:, 2], mine["depth"], rtol=1e-5, atol=1e-4)
    uv, z = frame.camera.project(p_c)
    gt = frame.gt_depth()
    u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    rel = np.abs(z - gt[v, u]) / gt[v, u]
    assert np.median(rel) < 0.02
    img = frame.image()
    assert np.array_equal(np.stack([mine["red"], mine["green"], mine["blue"]], 1), img[v, u])


def test_dense_clouds_only_for_chosen_frames(run_dir):
    files = sorted(p.name for p in (run_dir / "ply" / "dense").glob("*.ply"))
    assert files == ["000003.ply", "000005.ply"]
    depth = read_depth_npy(run_dir / "depth_npy" / "000005.npy")
    v = plyfile.PlyData.read(str(run_dir / "ply" / "dense" / "000005.ply"))["vertex"].data
    assert len(v) == int(np.isfinite(depth[::8, ::8]).sum())
    assert np.array_equal(np.sort(v["depth"]), np.sort(depth[::8, ::8][np.isfinite(depth[::8, ::8])]))
    assert np.all(np.isfinite(v["sigma_depth"])) and np.all(v["sigma_depth"] > 0)
