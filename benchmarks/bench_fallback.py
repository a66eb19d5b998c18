"""Fallback frames: measured AbsRel against the predicted relative error, by age (issue 12).

A frame whose own fit fails falls back on the previous fit. To get many such frames, the
images of a few stretches ("gaps") are replaced by flat grey (no features, so no points:
every gap frame falls back), while their disparity stays. For each gap frame and each
age the table shows the AbsRel of the depth the fallback would write and its predicted
relative error (median over the frame of sigma_D / D from the fallback fit's covariance),
for two fallbacks, in the same run:

* ``reused``: the baseline, the previous (alpha, beta) applied unchanged (vio-depth up to
  0.2.0);
* ``carried``: the previous fit carried to this frame through its anchor disparities
  (``vio_depth.rescale.temporal.carry_fit``, what the Rescaler does now).

The age and error limits are lifted (``max_fallback_age`` 1000, ``max_fallback_error``
inf) so the whole curve shows; the last lines give, for the default bound
``max_fallback_error`` = 0.10, the largest AbsRel among the fallback frames it admits and
the smallest age it refuses. SIMULATED disparity throughout.

    python benchmarks/bench_fallback.py                      # street, room, 7-Scenes (when present)
    python benchmarks/bench_fallback.py --sequences room
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEVEN = ROOT.parent / "shared" / "data" / "7scenes_redkitchen"
#: name -> (path, pairing preset, max eval depth, frames, gaps)
SEQUENCES = {
    "street": (ROOT / "sample_sequences" / "street", "kitti", 80.0, 90, [(30, 41), (70, 81)]),
    "room": (ROOT / "sample_sequences" / "room", "indoor", 10.0, 100, [(30, 45), (70, 85)]),
    "7scenes": (SEVEN, "indoor", 10.0, 110, [(40, 55), (80, 95)]),
}


def run(name: str, bound: float) -> list[tuple]:
    from vio_core.settings import override
    from vio_depth import Pipeline, PipelineSettings, open_sequence
    from vio_depth.evaluation import compute_metrics
    from vio_depth.rescale import FitSource, metric_depth, predicted_relative_error

    path, pairing, max_depth, n, gaps = SEQUENCES[name]
    seq = open_sequence(path)
    settings = PipelineSettings.from_presets(pairing=pairing)
    if name == "7scenes":
        settings = override(settings, {"disparity": {"source": "simulated"}})
    settings = override(settings, {"rescaler": {"max_fallback_age": 1000, "max_fallback_error": math.inf}})
    pipe = Pipeline(settings, sequence=seq)
    rows = []
    reused_fit = None  # the baseline: the last fit that gave depth, unchanged
    for i in range(min(n, len(seq))):
        frame = seq[i]
        if any(a <= i <= b for a, b in gaps):
            grey = np.full_like(frame.image(), 128)
            frame = replace(frame, load_image=lambda g=grey: g)
        res = pipe.process(frame)
        out = res.rescale
        if out is None:
            continue
        if out.source == FitSource.PREVIOUS_FIT:
            gt = seq[i].gt_depth()
            carried = compute_metrics(res.depth, gt, max_depth=max_depth).abs_rel
            old = compute_metrics(metric_depth(res.disparity, reused_fit), gt, max_depth=max_depth).abs_rel
            old_pred = predicted_relative_error(res.disparity, replace(reused_fit, covariance=out.fit.covariance))
            rows.append((i, out.age, old, old_pred, carried, out.predicted_error))
        elif out.fit is not None:
            reused_fit = out.fit
    return rows


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sequences", nargs="+", default=list(SEQUENCES), choices=list(SEQUENCES))
    p.add_argument("--bound", type=float, default=0.10)
    args = p.parse_args()
    for name in args.sequences:
        if not SEQUENCES[name][0].exists():
            print(f"{name}: not found, skipped")
            continue
        rows = run(name, args.bound)
        print(f"\n{name} (SIMULATED disparity), gaps {SEQUENCES[name][4]}")
        print(f"{'frame':>5s} {'age':>4s} {'reused AbsRel':>14s} {'carried AbsRel':>15s} {'carried predicted':>18s}")
        for i, age, old, _, new, pred in rows:
            print(f"{i:5d} {age:4d} {old:14.3f} {new:15.3f} {pred:18.3f}")
        admitted = [r for r in rows if r[5] <= args.bound]
        refused = [r for r in rows if r[5] > args.bound]
        by_age: dict[int, list[float]] = {}
        for r in rows:
            by_age.setdefault(r[1], []).append(r[4])
        print("median carried AbsRel by age: " + ", ".join(
            f"{a}: {np.median(v):.3f}" for a, v in sorted(by_age.items()) if a <= 12))
        print(f"bound {args.bound}: admits {len(admitted)} frames (ages <= "
              f"{max((r[1] for r in admitted), default=0)}), max carried AbsRel among them "
              f"{max((r[4] for r in admitted), default=float('nan')):.3f} (reused: "
              f"{max((r[2] for r in admitted), default=float('nan')):.3f}); refuses {len(refused)} "
              f"(youngest age {min((r[1] for r in refused), default=0)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
