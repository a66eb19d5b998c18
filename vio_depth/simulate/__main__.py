"""``python -m vio_depth.simulate --out sample_sequences``: regenerate the bundled samples.

The output is deterministic (seeded, no network): running it again reproduces every file
byte for byte on the same software stack; ``SHA256SUMS`` in the output folder lists them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from vio_core.errors import VioDepthError

from .generate import generate_sample, sample_names, write_checksums


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m vio_depth.simulate",
        description="Render the SIMULATED sample sequences (native format) deterministically.",
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder (e.g. sample_sequences)")
    parser.add_argument("--only", choices=sample_names(), action="append",
                        help="generate only this sample (repeatable; default: all)")
    parser.add_argument("--frames", type=int, default=None,
                        help="render only the first N frames (quick previews; not the bundled samples)")
    parser.add_argument("--quiet", action="store_true", help="no progress messages")
    args = parser.parse_args(argv)
    names = args.only or sample_names()
    log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        for name in names:
            start = time.perf_counter()
            generate_sample(name, args.out / name, n_frames=args.frames, progress=log)
            if log:
                log(f"{name}: done in {time.perf_counter() - start:.1f} s -> {args.out / name}")
        present = [n for n in sample_names() if (args.out / n / "sequence.json").is_file()]
        write_checksums(args.out, present)
    except VioDepthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
