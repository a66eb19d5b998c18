"""Benchmark: is the written depth trustworthy? Refusals, coverage and calibration (issue 20).

For each dataset and points path, the same run (`vio-depth run` through
:func:`vio_depth.run.run_sequence`, SIFT unless ``--matcher``, the sequence's poses, seed 0, CLI defaults) is
made twice in this one benchmark run:

* ``baseline`` -- the named baseline revision (``--baseline-rev``, default ``234a51e``,
  the code before issue 20), checked out into a temporary git worktree and run in a
  subprocess with its own packages;
* ``now`` -- this checkout.

Datasets (a missing folder is skipped; ``--data`` points at the shared data folder):

========  ==========================================  ========  ========  =========
name      folder                                      frames    pairing   max depth
========  ==========================================  ========  ========  =========
7scenes   DATA/7scenes_redkitchen (real, KinectFusion)  0-299    indoor    10 m
kitti     DATA/kitti_tiny (real, OXTS)                  0-6      kitti     80 m
street    sample_sequences/street (rendered)            all 130  kitti     80 m
room      sample_sequences/room (rendered)              all 120  indoor    10 m
========  ==========================================  ========  ========  =========

**Every dense figure uses SIMULATED disparity** (7-Scenes and KITTI: ``--disparity
simulated``, seed 0; the samples their own simulated maps).

Columns: ``written`` frames with depth (any status that writes depth) / processed;
``AbsRel`` / ``oracle`` over the written frames; ``bad`` written frames whose AbsRel
exceeds 2 x their own oracle + 0.02 (the issue's criterion); statuses.

Reliability (``now`` only): written frames binned by their predicted error; in each bin
the mean actual error: ``predicted_error`` against the rescaling's own error
(``rescale_abs_rel``: our depth against the oracle rescaling of the same disparity) and
``predicted_abs_rel`` against AbsRel. A bin is flagged ``!`` when the two differ by more
than a factor of 2.

Run: ``python benchmarks/bench_trust.py [--datasets 7scenes,kitti,street,room]
[--paths two-view,landmarks] [--data DIR] [--baseline-rev REV | --no-baseline]
[--matcher sift|klt] [--edge-guard F]`` (``--matcher klt --edge-guard 0.1``: the KLT front end
as ``vio-depth run --matcher klt --edge-guard 0.1``; both sides get the same; a baseline older
than the matcher presets it names fails).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from baseline_checkout import baseline_checkout
from bench_landmarks import DATASETS, PATHS, Dataset  # the same datasets, pairings and paths

REPO = Path(__file__).resolve().parents[1]


WRITES = {"ok", "fallback_scale_only", "fallback_previous_fit"}

# the run, as a script: it imports the packages of the checkout it is given (argv[1])
_RUNNER = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from vio_depth import Pipeline, PipelineSettings, open_sequence
from vio_depth.run import RunSettings, run_sequence
folder, points, pairing, disparity, n, max_depth, out, matcher, guard = sys.argv[2:11]
settings = PipelineSettings.from_presets(points=points, pairing=pairing, matcher=matcher)
overrides = {"disparity": {"source": disparity}}
if guard != "none":
    overrides["rescaler"] = {"max_disparity_spread": float(guard)}
settings = PipelineSettings.from_dict(overrides, settings)
seq = open_sequence(folder)
run_sequence(seq, Pipeline(settings, sequence=seq), Path(out),
             RunSettings(max_frames=int(n), max_eval_depth=float(max_depth)), progress=False)
"""


def run(checkout: Path, ds: Dataset, folder: Path, n: int, path: str, out: Path, matcher: str = "sift",
        edge_guard: float | None = None) -> tuple[dict, list[dict]]:
    """One run in a subprocess with ``checkout``'s packages: ``(metrics.json, frame records)``."""
    cmd = [sys.executable, "-c", _RUNNER, str(checkout), str(folder), PATHS[path], ds.pairing, ds.disparity,
           str(n), str(ds.max_depth), str(out), matcher, "none" if edge_guard is None else str(edge_guard)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if not (out / "metrics.json").exists():
        raise RuntimeError(f"run failed ({checkout.name}, {ds.name}, {path}): {proc.stderr[-2000:]}")
    lines = [json.loads(x) for x in (out / "frames.jsonl").read_text().splitlines() if x.strip()]
    return json.loads((out / "metrics.json").read_text()), [r for r in lines if r.get("record") == "frame"]


def summary(metrics: dict, frames: list[dict], points: str) -> dict:
    written = [f for f in frames if f["status"] in WRITES]
    bad = [f["frame"] for f in written if f.get("abs_rel") is not None and f.get("oracle_abs_rel") is not None
           and f["abs_rel"] > 2 * f["oracle_abs_rel"] + 0.02]
    row = metrics["metrics"].get(points, {})
    oracle = metrics["metrics"].get("oracle", {})
    return {"written": len(written), "processed": metrics["frames_processed"], "abs_rel": row.get("abs_rel"),
            "delta1": row.get("delta1"), "oracle": oracle.get("abs_rel"), "bad": bad,
            "statuses": metrics["status_counts"],
            "seconds": float(np.median([f["seconds"] for f in frames])) if frames else float("nan")}


def _fmt(x, spec=".4f"):
    return "   -   " if x is None else format(x, spec)


def print_row(label: str, s: dict) -> None:
    statuses = ", ".join(f"{k} {v}" for k, v in sorted(s["statuses"].items()))
    print(f"  {label:9s} written {s['written']:3d}/{s['processed']:<3d} AbsRel {_fmt(s['abs_rel'])} "
          f"delta1 {_fmt(s['delta1'])} oracle {_fmt(s['oracle'])} bad {len(s['bad']):3d}  "
          f"s/fr {s['seconds']:.3f}  [{statuses}]")
    if s["bad"]:
        print(f"            bad frames: {s['bad'][:30]}{' ...' if len(s['bad']) > 30 else ''}")


EDGES = (0.0, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, np.inf)


def reliability(frames: list[dict]) -> list[tuple]:
    """Rows ``(kind, lo, hi, n, mean predicted, mean actual, ratio)`` over the written frames."""
    written = [f for f in frames if f["status"] in WRITES]
    rows = []
    for kind, pk, ak in (("rescaling", "predicted_error", "rescale_abs_rel"),
                         ("AbsRel", "predicted_abs_rel", "abs_rel")):
        pairs = np.array([(f[pk], f[ak]) for f in written if f.get(pk) is not None and f.get(ak) is not None])
        if not len(pairs):
            continue
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            sel = (pairs[:, 0] >= lo) & (pairs[:, 0] < hi)
            if sel.any():
                p, a = pairs[sel, 0].mean(), pairs[sel, 1].mean()
                rows.append((kind, lo, hi, int(sel.sum()), p, a, p / a if a > 0 else np.inf))
    return rows


def print_reliability(rows) -> None:
    for kind, lo, hi, n, p, a, ratio in rows:
        flag = "" if 0.5 <= ratio <= 2.0 else "  !"
        print(f"    {kind:9s} predicted {lo:.3f}-{hi:.3f}: n {n:3d}  mean predicted {p:.4f}  mean actual {a:.4f}  "
              f"predicted/actual {ratio:5.2f}{flag}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default="7scenes,kitti,street,room")
    parser.add_argument("--paths", default="two-view,landmarks")
    parser.add_argument("--data", type=Path, default=REPO / ".." / "shared" / "data")
    parser.add_argument("--baseline-rev", default="234a51e", help="git revision run as the named baseline")
    parser.add_argument("--no-baseline", action="store_true")
    parser.add_argument("--frames", type=int, default=None, help="cap every dataset at N frames")
    parser.add_argument("--json", type=Path, default=None, help="also write every summary and table here")
    parser.add_argument("--matcher", default="sift", help="matcher preset (sift, klt, ...), both sides")
    parser.add_argument("--edge-guard", type=float, default=None, metavar="F",
                        help="the rescaler's max_disparity_spread, as vio-depth run --edge-guard (both sides)")
    args = parser.parse_args(argv)
    print(f"bench_trust, {datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPU cores, python "
          f"{platform.python_version()}, load average {os.getloadavg()[0]:.1f}, baseline "
          f"{'none' if args.no_baseline else args.baseline_rev}, matcher {args.matcher}, edge guard "
          f"{args.edge_guard}")
    print("NOTE: dense figures use SIMULATED disparity on every dataset (see the module docstring)")
    report = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with contextlib.ExitStack() as stack:
            checkouts = {"now": REPO}
            if not args.no_baseline:
                checkouts = {"baseline": stack.enter_context(baseline_checkout(args.baseline_rev, tmp / "baseline")),
                             "now": REPO}
            for name in args.datasets.split(","):
                ds = DATASETS[name]
                folder = ds.folder(args.data)
                if not folder.exists():
                    print(f"\n{name}: {folder} missing, skipped")
                    continue
                n = min(ds.frames or 10**9, args.frames or 10**9)
                for path in args.paths.split(","):
                    print(f"\n{name} ({folder.name}), {path}, pairing '{ds.pairing}', max depth {ds.max_depth:g} m",
                          flush=True)
                    for label, checkout in checkouts.items():
                        metrics, frames = run(checkout, ds, folder, n, path, tmp / f"{label}-{name}-{path}",
                                              args.matcher, args.edge_guard)
                        s = summary(metrics, frames, PATHS[path])
                        print_row(label, s)
                        report[f"{name}/{path}/{label}"] = s
                        if label == "now":
                            rows = reliability(frames)
                            print_reliability(rows)
                            report[f"{name}/{path}/reliability"] = rows
                    sys.stdout.flush()
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
