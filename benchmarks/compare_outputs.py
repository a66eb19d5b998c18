"""Are the outputs of a refactored tree identical to a baseline revision's? (issue 22)

Runs the same matrix of ``vio-depth run`` commands with two checkouts -- the baseline
revision (``--baseline-rev``, default ``b331fd9``: main before issue 22), checked out into a
temporary git worktree, and the candidate tree (``--candidate``, default this checkout) --
each in a subprocess with ``PYTHONPATH`` set to its checkout and the same virtual
environment, the same absolute input paths and the same relative output folder, and
compares every output file:

* ``.json`` / ``.jsonl``: parsed, with the fields that legitimately differ between two runs
  removed (wall-clock ``seconds``, ``timings``, ``wall_s``, a folder's random ``id`` and
  ``created`` time), then compared exactly (floats included);
* everything else (depth PNGs, ``.npy``, PLY, report plots, trajectory): byte for byte;
* ``report.md`` / ``index.html``: byte for byte after dropping the lines that state the run's
  duration.

A file present on one side only counts as a difference. The table lists, per run, the files
compared, identical and different (the first few named).

Runs (``--quick``: the first N frames only; real data is skipped when absent):

=================  ======================================================================
street-gt          sample street, --poses gt, all exports (npy, preview, PLY, report)
street-imu         sample street, --poses imu
street-landmarks   sample street, --points landmarks
room-gt            sample room, --pairing indoor --max-depth 10
room-imu           sample room, --poses imu, indoor
street-vio         sample street, --poses vio (visual-inertial odometry from the images and IMU;
                   --quick: its 30 frames are all still initialising, exit code 3 on both sides)
room-vio           sample room, --poses vio, indoor
room-vio-klt       sample room, --poses vio --matcher klt, indoor (the tracking matcher's path)
kitti-gt / -imu    ../shared/data/kitti_tiny (real, OXTS), --disparity simulated
euroc-gt / -imu    ../shared/data/euroc_v101_static (real, still): a smooth synthetic disparity
                   written to files (the slice has no depth; only the pose/points path matters)
=================  ======================================================================

Run: ``python benchmarks/compare_outputs.py [--candidate DIR] [--baseline-rev REV]
[--quick] [--runs street-gt,room-imu] [--keep DIR]``. Exit code 1 when anything differs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from baseline_checkout import baseline_checkout

REPO = Path(__file__).resolve().parents[1]
DATA = (REPO / ".." / "shared" / "data").resolve()
VENV_BIN = REPO / ".venv" / "bin"
EXPORTS = ["--save-npy", "--save-preview", "--save-ply", "sparse,dense", "--report"]
#: JSON keys whose values differ between two identical runs (wall clock, random ids)
VOLATILE = {"seconds", "timings", "wall_s", "id", "created"}
QUICK_FRAMES = 30


def runs(quick: bool, disparity_dir: Path) -> dict[str, list[str]]:
    street = str(REPO / "sample_sequences" / "street")
    room = str(REPO / "sample_sequences" / "room")
    indoor = ["--pairing", "indoor", "--max-depth", "10"]
    table = {
        "street-gt": [street, *EXPORTS],
        "street-imu": [street, "--poses", "imu"],
        "street-landmarks": [street, "--points", "landmarks"],
        "room-gt": [room, *indoor],
        "room-imu": [room, *indoor, "--poses", "imu"],
        "street-vio": [street, "--poses", "vio"],
        "room-vio": [room, *indoor, "--poses", "vio"],
        "room-vio-klt": [room, *indoor, "--poses", "vio", "--matcher", "klt"],
    }
    if (DATA / "kitti_tiny").is_dir():
        kitti = [str(DATA / "kitti_tiny"), "--disparity", "simulated"]
        table["kitti-gt"] = kitti
        table["kitti-imu"] = [*kitti, "--poses", "imu"]
    if (DATA / "euroc_v101_static").is_dir():
        euroc = [str(DATA / "euroc_v101_static"), "--disparity-dir", str(disparity_dir), "--pairing", "indoor",
                 "--max-depth", "10"]
        table["euroc-gt"] = euroc
        table["euroc-imu"] = [*euroc, "--poses", "imu"]
    if quick:
        table = {name: [*args, "--max-frames", str(QUICK_FRAMES)] for name, args in table.items()}
    return table


def write_euroc_disparity(folder: Path) -> None:
    """A smooth, deterministic disparity (float32 480x752) per EuRoC frame: a ramp, nearer at the bottom."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = np.linspace(0.2, 1.0, 480, dtype=np.float32)[:, None]
    cols = np.linspace(0.0, 0.1, 752, dtype=np.float32)[None, :]
    disparity = (rows + cols).astype(np.float32)
    for png in sorted((DATA / "euroc_v101_static" / "mav0" / "cam0" / "data").glob("*.png")):
        np.save(folder / f"{png.stem}.npy", disparity)


def run_side(checkout: Path, workdir: Path, table: dict[str, list[str]]) -> dict[str, str]:
    """Run every command of ``table`` with ``checkout``'s code into ``workdir/out/<name>``; the last stderr lines."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    tails = {}
    for name, args in table.items():
        start = time.perf_counter()
        proc = subprocess.run([str(VENV_BIN / "vio-depth"), "run", *args, "--out", f"out/{name}", "--no-progress"],
                              cwd=workdir, env=env, capture_output=True, text=True)
        tails[name] = f"rc {proc.returncode}, {time.perf_counter() - start:.0f} s"
        if proc.returncode != 0:
            tails[name] += ": " + (proc.stderr.strip().splitlines() or ["?"])[-1][:200]
        print(f"  {checkout.name}: {name}: {tails[name]}", flush=True)
    return tails


def _strip(value):
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if k not in VOLATILE}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def normalised(path: Path) -> bytes:
    """The content of ``path`` that must be identical between two runs."""
    if path.suffix == ".json":
        return json.dumps(_strip(json.loads(path.read_text())), sort_keys=True).encode()
    if path.suffix == ".jsonl":
        lines = [json.dumps(_strip(json.loads(line)), sort_keys=True) for line in path.read_text().splitlines() if line]
        return "\n".join(lines).encode()
    if path.suffix in (".md", ".html"):
        keep = [line for line in path.read_text().splitlines()
                if not any(word in line for word in ("seconds", "wall", "frames/s", "created", " s |", "s/frame"))]
        return "\n".join(keep).encode()
    return path.read_bytes()


def compare(a: Path, b: Path) -> tuple[int, list[str]]:
    """(files compared, files that differ) between run folders ``a`` and ``b``."""
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file()} if a.is_dir() else set()
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file()} if b.is_dir() else set()
    differ = sorted(str(p) + (" (one side only)" if p not in files_a or p not in files_b else "")
                    for p in files_a ^ files_b)
    for rel in sorted(files_a & files_b):
        if hashlib.sha256(normalised(a / rel)).digest() != hashlib.sha256(normalised(b / rel)).digest():
            differ.append(str(rel))
    return len(files_a | files_b), differ


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--candidate", type=Path, default=REPO, help="checkout to test (default: this one)")
    parser.add_argument("--baseline-rev", default="b331fd9")
    parser.add_argument("--quick", action="store_true", help=f"first {QUICK_FRAMES} frames of each run")
    parser.add_argument("--runs", default="", help="comma-separated subset of the run names")
    parser.add_argument("--keep", type=Path, help="keep both sides' outputs under this folder")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="vio-compare-") as tmp:
        work = args.keep.resolve() if args.keep else Path(tmp)
        table = runs(args.quick, work / "euroc_disparity")
        if args.runs:
            wanted = args.runs.split(",")
            unknown = sorted(set(wanted) - set(table))
            if unknown:
                raise SystemExit(f"unknown run(s) {unknown}; valid: {', '.join(table)}")
            table = {name: table[name] for name in wanted}
        if any(name.startswith("euroc") for name in table):
            write_euroc_disparity(work / "euroc_disparity")
        sides = {}
        with baseline_checkout(args.baseline_rev, Path(tmp) / "baseline-checkout") as base:
            for side, checkout in (("baseline", base), ("candidate", args.candidate.resolve())):
                (work / side).mkdir(parents=True, exist_ok=True)
                print(f"{side}: {checkout}", flush=True)
                sides[side] = run_side(checkout, work / side, table)
        print(f"\nbaseline {args.baseline_rev} vs candidate {args.candidate.resolve()}"
              f"{' (--quick: first %d frames)' % QUICK_FRAMES if args.quick else ''}\n")
        print("| run | baseline | candidate | files | identical | differ |")
        print("|---|---|---|---|---|---|")
        failed = False
        for name in table:
            n, differ = compare(work / "baseline" / "out" / name, work / "candidate" / "out" / name)
            failed |= bool(differ) or sides["baseline"][name].split(",")[0] != sides["candidate"][name].split(",")[0]
            shown = ", ".join(differ[:4]) + (f" (+{len(differ) - 4})" if len(differ) > 4 else "")
            print(f"| {name} | {sides['baseline'][name]} | {sides['candidate'][name]} | {n} | {n - len(differ)} "
                  f"| {shown or '-'} |")
    print("\nRESULT:", "DIFFERENT" if failed else "IDENTICAL")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
