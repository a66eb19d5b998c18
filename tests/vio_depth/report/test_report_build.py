"""The report of synthetic run folders: sections, omissions with reasons, links that resolve anywhere."""

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from vio_core.errors import InputError
from vio_depth.io.depth_png import write_depth_png
from vio_depth.report import build_report, load_run, status_runs

_spec = importlib.util.spec_from_file_location("report_links", Path(__file__).with_name("report_links.py"))
report_links = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(report_links)


def _frames(n=8, gt=False):
    recs = []
    for i in range(n):
        ok = i >= 2
        rec = {"frame": i, "stem": f"{i:06d}", "status": "ok" if ok else "no_pair",
               "reason": "first frame: no keyframe to pair with yet" if i == 0 else ("x" if ok else "too close"),
               "matches": 100 + i, "triangulated_points": 50 + i, "inliers": 40 + i,
               "alpha": 0.03 + 0.001 * i if ok else None, "beta": 0.01 if ok else None, "r2": 0.9 - 0.01 * i,
               "fit_diagnostics": {"alpha": 0.03, "beta": 0.01, "sigma_alpha": 0.001, "sigma_beta": 0.002}}
        if gt and ok:
            rec.update(abs_rel=0.01 * i, oracle_abs_rel=0.01, points_rel_err_median=0.01, points_rel_err_p90=0.03)
        recs.append(rec)
    return recs


def _old_run(tmp_path, n=8, gt=False, header=None, metrics=None):
    """A run folder as today's vio-depth writes it: frames.jsonl, depth/*.png (+ metrics.json)."""
    out = tmp_path / "run"
    (out / "depth").mkdir(parents=True)
    recs = _frames(n, gt)
    lines = ([json.dumps(header)] if header else []) + [json.dumps(r) for r in recs]
    (out / "frames.jsonl").write_text("\n".join(lines) + "\n")
    for r in recs:
        if r["status"] == "ok":
            d = np.full((24, 32), 2.0 + r["frame"], np.float32)
            d[:3] = np.nan
            write_depth_png(out / "depth" / f"{r['stem']}.png", d)
    if metrics is not None:
        (out / "metrics.json").write_text(json.dumps(metrics))
    return out


def test_old_run_without_header_or_ground_truth_degrades_with_notes(tmp_path):
    out = _old_run(tmp_path)
    res = build_report(out)
    assert res.html == out / "report" / "index.html" and res.markdown.is_file()
    html = res.html.read_text()
    for title in ("Run", "Summary", "Scale over time", "Points and inliers", "Status timeline",
                  "Accuracy against ground truth", "Best, median and worst frames", "Files of this run"):
        assert f">{title}</h2>" in html
        assert f"## {title}" in res.markdown.read_text()
    assert "Not recorded by this run: version, command line, settings" in html
    assert any("AbsRel" in o for o in res.omitted) and any("depth metrics" in o for o in res.omitted)
    assert "plots/scale.png" in res.images and "plots/dense_error.png" not in res.images
    # thumbnails drawn from the 16-bit depth PNGs, ranked by R² (no ground truth)
    assert "ranked by R²" in html and "drawn from the 16-bit depth PNGs" in html
    thumbs = sorted(p.name for p in (out / "report" / "thumbs").iterdir())
    assert thumbs == ["000002_preview.png", "000004_preview.png", "000007_preview.png"]
    # the status table lists the frames without depth with their reason
    assert "<td>0–1</td><td>no_pair</td><td>first frame: no keyframe to pair with yet</td>" in html
    for page in (res.html, res.markdown):
        assert report_links.broken_links(page) == [] and report_links.no_network(page)


def test_header_record_and_ground_truth_fill_every_section(tmp_path):
    header = {"record": "run", "version": "9.9.9", "command_line": ["vio-depth", "run", "seq", "--out", "x y"],
              "settings": {"matcher": "sift", "pairing": {"min_rotation_deg": 5.0}}}
    metrics = {"frames_in_sequence": 100, "metrics": {"sfm": {"delta1": 0.99, "abs_rel": 0.02, "rmse": 1.5,
                                                              "n_frames": 6}},
               "point_accuracy": {"frames": 6, "points_per_frame_median": 50.0, "rel_err_median_of_frames": 0.01,
                                  "rel_err_p90_median_of_frames": 0.03}, "disparity_kind": "simulated"}
    out = _old_run(tmp_path, gt=True, header=header, metrics=metrics)
    run = load_run(out)
    assert run.header["version"] == "9.9.9" and len(run.frames) == 8  # the header is not a frame
    res = build_report(out)
    html = res.html.read_text()
    assert "9.9.9" in html and "vio-depth run seq --out 'x y'" in html and "min_rotation_deg" in html
    assert "SIMULATED" in html and "(100 frames in the sequence)" in html
    assert {"plots/dense_error.png", "plots/point_accuracy.png"} <= set(res.images)
    assert "ranked by AbsRel" in html and "best: frame 2" in html and "worst: frame 7" in html
    assert not any("AbsRel per frame" in o for o in res.omitted)


def test_settings_in_metrics_json_and_run_info_fallback(tmp_path):
    out = _old_run(tmp_path, metrics={"version": "1.2.3", "command": "vio-depth run a --out b"})
    assert load_run(out).info() == {"version": "1.2.3", "command_line": "vio-depth run a --out b", "settings": None}
    html = build_report(out, run_info={"settings": {"matcher": "disk+lightglue"}, "version": "ignored"}).html.read_text()
    assert "1.2.3" in html and "disk+lightglue" in html and "ignored" not in html


def test_report_folder_copied_elsewhere_still_resolves(tmp_path):
    out = _old_run(tmp_path, gt=True)
    res = build_report(out)
    moved = tmp_path / "elsewhere" / "copy"
    shutil.copytree(out / "report", moved)  # only the report folder, not the run
    shutil.rmtree(out)
    for page in (moved / "index.html", moved / "report.md"):
        assert report_links.links(page) and report_links.broken_links(page) == []
    assert len(report_links.links(moved / "report.md")) == len(res.images)


def test_unreadable_lines_are_noted_and_missing_runs_fail_cleanly(tmp_path):
    out = _old_run(tmp_path)
    with open(out / "frames.jsonl", "a") as fh:
        fh.write("{not json\n[1, 2]\n")
    run = load_run(out)
    assert len(run.frames) == 8 and "skipped 2 unreadable line(s)" in run.notes[0]
    assert "Reading notes" in build_report(out).sections
    with pytest.raises(InputError, match="no such run folder"):
        build_report(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="frames.jsonl"):
        build_report(tmp_path / "empty")


def test_status_runs_group_consecutive_frames():
    recs = [{"frame": i, "status": s, "reason": f"r{i}"} for i, s in enumerate(["no_pair", "no_pair", "ok", "ok",
                                                                                  "too_few_points", "ok"])]
    assert status_runs(recs) == [(0, 1, "no_pair", "r0"), (2, 3, "ok", "r2"), (4, 4, "too_few_points", "r4"),
                                 (5, 5, "ok", "r5")]


def test_report_command_prints_where_it_wrote(tmp_path, capsys):
    from vio_depth.cli import main

    out = _old_run(tmp_path)
    assert main(["report", str(out), "--to", str(tmp_path / "rep")]) == 0
    assert "rep/index.html" in capsys.readouterr().out and (tmp_path / "rep" / "plots" / "scale.png").is_file()
    assert main(["report", str(tmp_path / "missing")]) == 1
    assert capsys.readouterr().err.startswith("vio-depth: error:")
    assert sys.modules.get("matplotlib.pyplot") is None  # the OO API only: no global pyplot state
