"""The paper-reference baseline (vio_depth/baselines/paper_reference.py) next to ours and the oracle, one sequence.

A thin front end of `vio-depth eval` (the same scoring, :mod:`vio_depth.experiments`): the
variants ``oracle``, ``sfm`` and ``paper-reference`` on the same frames, printed as a table,
plus the three on the frames where all gave depth. Run from the repository root::

    python -m benchmarks.bench_paper_reference sample_sequences/street [--frames 0:60]
    python -m benchmarks.bench_paper_reference sample_sequences/room --indoor
    python -m benchmarks.bench_paper_reference ../shared/data/kitti_tiny --disparity simulated

For many sequences, tables and figures use ``vio-depth eval`` (docs/evaluation.md).
"""

from __future__ import annotations

import argparse
import sys

from vio_depth.experiments import (
    FrameScore,
    FrameSelection,
    SequenceEntry,
    evaluate_variant,
    open_task,
    parse_variant,
    resolve_entry,
)
from vio_depth.experiments.scores import common_frames, mean_on

VARIANTS = ("oracle", "sfm", "paper-reference")


def _fmt(x, spec: str) -> str:
    return format("-", ">" + spec.split(".")[0]) if x is None else format(x, spec)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="paper-reference baseline vs ours and the oracle on one sequence")
    ap.add_argument("sequence")
    ap.add_argument("--indoor", action="store_true", help="indoor profile: 10 m cap, indoor pairing presets")
    ap.add_argument("--frames", default=None, metavar="A:B[:S]", help="frames (default: all)")
    ap.add_argument("--disparity", default="sequence", choices=["sequence", "simulated"])
    ap.add_argument("--preset", default=None, help="paper-reference preset (default: the profile's; "
                                                   "published_kitti = previous frame only)")
    args = ap.parse_args(argv)
    entry = SequenceEntry(path=args.sequence, profile="indoor" if args.indoor else "outdoor",
                          frames=FrameSelection.parse(args.frames) if args.frames else FrameSelection(),
                          disparity=args.disparity, paper=args.preset)
    resolved = resolve_entry(entry)
    ctx = open_task(args.sequence, resolved.task_settings(None))
    outs = {v: evaluate_variant(ctx, parse_variant(v)) for v in VARIANTS}
    kind = outs["oracle"]["disparity_kind"]
    print(f"{args.sequence}: frames {entry.frames.describe()} ({len(resolved.evaluate)} evaluated), "
          f"{resolved.mask.describe()}, disparity {kind}" + (" (SIMULATED)" if kind == "simulated" else ""))
    print(f"{'':16} {'delta1':>8} {'AbsRel':>8} {'RMSE':>8} {'coverage':>9} {'pts/frame':>9} {'pt err':>7} {'s/frame':>8}")
    for v, out in outs.items():
        r = out["row"]
        print(f"{v:16} {_fmt(r['delta1'], '8.4f')} {_fmt(r['abs_rel'], '8.4f')} {_fmt(r['rmse'], '8.3f')} "
              f"{_fmt(r['coverage'], '9.3f')} {_fmt(r['points_per_frame'], '9.0f')} {_fmt(r['point_error'], '7.3f')} "
              f"{_fmt(r['seconds_per_frame'], '8.3f')}")
    scores = {v: [FrameScore.from_json(f) for f in out["frames"]] for v, out in outs.items()}
    common = common_frames(scores.values())
    print(f"on the {len(common)} frames where all three gave depth:")
    for v in VARIANTS:
        m = mean_on(scores[v], common)
        print(f"{v:16} {_fmt(m['delta1'], '8.4f')} {_fmt(m['abs_rel'], '8.4f')} {_fmt(m['rmse'], '8.3f')}")
    print(f"paper-reference statuses: {outs['paper-reference']['row']['statuses']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
