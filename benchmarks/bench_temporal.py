"""Temporal filter on (alpha, beta): flicker and accuracy, filter on vs off, same run.

Flicker is the frame-to-frame variation of the rescaled median depth that the true
scene does not explain:  for each frame t with metric depth, e_t = log(median of the
predicted depth / median of the ground-truth depth) over the pixels valid in both;
flicker = RMS of (e_t - e_{t-1}) over consecutive evaluated frames. The bundled samples
are static scenes (nothing moves but the camera), so every stretch is a static-scene
stretch; ``--frames A:B`` restricts the evaluation to a slice.

The baseline is the same pipeline with the filter off (rescaler preset ``per_frame``),
on the same frames, matches and points (identical seeds).

    python benchmarks/bench_temporal.py                       # street + room samples
    python benchmarks/bench_temporal.py --sequences street --frames 20:80

Exits non-zero when, on any sequence, the filter does not reduce flicker or worsens AbsRel
by more than 2 % (relative).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = {"street": ("kitti", 80.0), "room": ("indoor", 10.0)}


def run(sequence_name: str, temporal: bool, frames: slice, seed: int) -> dict:
    from vio_core.settings import override
    from vio_depth.evaluation.metrics import average_metrics, compute_metrics
    from vio_depth.io import open_sequence
    from vio_depth.pipeline import Pipeline, PipelineSettings

    pairing, max_depth = SAMPLES[sequence_name]
    seq = open_sequence(ROOT / "sample_sequences" / sequence_name)
    settings = PipelineSettings.from_presets(pairing=pairing, rescaler="streaming" if temporal else "per_frame")
    settings = override(settings, {"rescaler": {"ransac": {"seed": seed}}})
    pipe = Pipeline(settings, sequence=seq)
    stop = len(seq) if frames.stop is None else min(frames.stop, len(seq))
    start = frames.start or 0
    errors, metrics = [], []
    for i in range(stop):  # frames before the slice still run: the filter needs its history
        frame = seq[i]
        res = pipe.process(frame)
        if i < start:
            continue
        if res.depth is None:
            errors.append(np.nan)
            continue
        gt = frame.gt_depth()
        both = np.isfinite(res.depth) & (gt > 0) & (gt <= max_depth)
        errors.append(float(np.log(np.median(res.depth[both]) / np.median(gt[both]))))
        metrics.append(compute_metrics(res.depth, gt, max_depth=max_depth))
    e = np.asarray(errors)
    steps = np.diff(e)
    steps = steps[np.isfinite(steps)]
    avg = average_metrics(metrics)
    return {
        "flicker": float(np.sqrt(np.mean(steps**2))) if len(steps) else float("nan"),
        "abs_rel": float(avg.abs_rel),
        "delta1": float(avg.delta1),
        "frames": int(np.isfinite(e).sum()),
        "median_scale_error": float(np.nanmedian(np.abs(e))),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default="street,room")
    ap.add_argument("--frames", default=":", help="slice A:B of frames to evaluate (default all)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    a, _, b = args.frames.partition(":")
    frames = slice(int(a) if a else None, int(b) if b else None)

    ok = True
    print("Temporal filter on (alpha, beta) vs the same pipeline without it (baseline: filter off)")
    print("flicker = RMS frame-to-frame change of log(median pred depth / median GT depth); SIMULATED disparity")
    print(f"{'sequence':9s} {'filter':7s} {'flicker':>9s} {'AbsRel':>8s} {'delta1':>8s} {'frames':>7s}   verdict")
    for name in args.sequences.split(","):
        off = run(name, False, frames, args.seed)
        on = run(name, True, frames, args.seed)
        less_flicker = on["flicker"] < off["flicker"]
        abs_rel_change = on["abs_rel"] / off["abs_rel"] - 1.0
        passed = less_flicker and abs_rel_change <= 0.02
        ok &= passed
        for label, r in (("off", off), ("on", on)):
            print(f"{name:9s} {label:7s} {r['flicker']:9.4f} {r['abs_rel']:8.4f} {r['delta1']:8.4f} {r['frames']:7d}")
        print(f"{'':9s} {'':7s} flicker x{on['flicker'] / off['flicker']:.2f}, AbsRel {abs_rel_change:+.1%}"
              f"   {'PASS' if passed else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
