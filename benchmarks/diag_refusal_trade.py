"""Diagnosis: what a tighter bound on the predicted error would refuse, per finished run.

For each run folder given (``vio-depth run ... --out DIR`` on a sequence with ground-truth
depth), from its ``frames.jsonl``: frames written, wrong ones among them (AbsRel above
2 x the frame's oracle AbsRel + 0.02, the measure of ``bench_vio.py``) with their
``predicted_error``, and -- after the fact -- how many written frames and wrong ones a bound
of each ``--bounds`` value on ``predicted_error`` would keep. After the fact means the run is
not repeated: a run with the tighter ``--max-fit-error`` would also try its fallbacks on the
refused frames and filter differently, so read the kept counts as an upper bound on what it
writes.

Run: ``python benchmarks/diag_refusal_trade.py RUN_DIR [RUN_DIR ...] [--bounds 0.025,0.02,0.015]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for path in (REPO, REPO / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from bench_vio import wrong_frames  # noqa: E402  (the benchmarks' one definition of a wrong frame)
from vio_depth.run import read_frames_jsonl  # noqa: E402


def trade_row(name: str, records: list[dict], bounds: list[float]) -> str:
    written = [r for r in records if r.get("alpha") is not None]
    bad = set(wrong_frames(records))
    wrong = [r for r in written if r["frame"] in bad]
    cells = [name, f"{len(written)}/{len(records)}", str(len(wrong))]
    for bound in bounds:
        kept = [r for r in written if (r.get("predicted_error") or 0.0) <= bound]
        cells.append(f"{len(kept)}, {sum(r['frame'] in bad for r in kept)}")
    cells.append(", ".join(f"{r['frame']} ({r['predicted_error']:.3f})" for r in wrong) or "-")
    return "| " + " | ".join(cells) + " |"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished run folders (with frames.jsonl)")
    parser.add_argument("--bounds", default="0.025,0.02,0.015", help="bounds on predicted_error to try")
    args = parser.parse_args(argv)
    bounds = [float(b) for b in args.bounds.split(",")]
    print("| run | written | wrong | " + " | ".join(f"kept, wrong at <= {b:g}" for b in bounds)
          + " | wrong frames (predicted error) |")
    print("|---" * (4 + len(bounds)) + "|")
    for run in args.runs:
        records = read_frames_jsonl(run / "frames.jsonl")[1]
        print(trade_row(run.name, records, bounds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
