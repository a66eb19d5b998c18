"""A 10 000-frame run: memory stays flat, open files stay bounded (issue 23).

A robot log is long. This benchmark builds a native sequence of ``--frames`` frames (default
10 000) from the bundled street sample (130 frames, 640x256, SIMULATED disparity from its
ground-truth depth): the frames ping-pong (0..129, 128..1, 0..129, ...) so that the camera
path stays continuous, with increasing timestamps; images and depth PNGs are hard links (no
disk space). It then runs ``vio-depth run SEQ --out OUT`` in a subprocess with every default
(evaluation against the ground truth, the offline backward pass, every default output) and
samples the subprocess every 0.25 s from ``/proc/<pid>``: resident memory (``VmRSS``), open
file descriptors (``/proc/<pid>/fd``) and threads, against the frames completed so far (the
lines of the run's journal).

Prints a table (one row per tenth of the run) and compares with a named baseline in the
same run, **the state at frame 1 000**:

* memory: RSS at the end <= 1.1 x RSS at frame 1 000 (+ 64 MiB for the run-end outputs);
* open files: the most descriptors ever open <= those at frame 1 000 + 8.

Exits 1 when a criterion fails.

    python benchmarks/bench_long_run.py                    # 10 000 frames (~15 min on 2 cores)
    python benchmarks/bench_long_run.py --frames 2000      # quicker
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STREET = ROOT / "sample_sequences" / "street"
BASELINE_FRAME = 1000


def ping_pong(n_source: int, n: int) -> list[int]:
    """Source frame of each of ``n`` frames: 0..N-1, N-2..1, 0..N-1, ... (a continuous path)."""
    cycle = list(range(n_source)) + list(range(n_source - 2, 0, -1))
    return [cycle[i % len(cycle)] for i in range(n)]


def build_sequence(dst: Path, n: int) -> Path:
    """A native sequence of ``n`` frames ping-ponged over the street sample (hard links)."""
    rows = [ln.split() for ln in (STREET / "frames.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    poses = [ln.split() for ln in (STREET / "poses.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    pose_at = {float(p[0]): p[1:] for p in poses}
    t = [float(r[0]) for r in rows]
    dt = (t[-1] - t[0]) / (len(t) - 1)
    (dst / "images").mkdir(parents=True)
    (dst / "depth").mkdir()
    frames, pose_lines = [], []
    for i, k in enumerate(ping_pong(len(rows), n)):
        stem = Path(rows[k][1]).stem
        name = f"{i:06d}"
        os.link(STREET / "images" / f"{stem}.jpg", dst / "images" / f"{name}.jpg")
        os.link(STREET / "depth" / f"{stem}.png", dst / "depth" / f"{name}.png")
        ti = t[0] + i * dt
        frames.append(f"{ti:.6f} images/{name}.jpg")
        pose_lines.append(f"{ti:.6f} " + " ".join(pose_at[t[k]]))
    (dst / "frames.txt").write_text("\n".join(frames) + "\n")
    (dst / "poses.txt").write_text("# t tx ty tz qx qy qz qw\n" + "\n".join(pose_lines) + "\n")
    meta = json.loads((STREET / "sequence.json").read_text())
    meta.pop("imu", None)  # the ping-pong path reverses: an IMU stream would not match it
    meta["name"] = f"street_pingpong_{n}"
    (dst / "sequence.json").write_text(json.dumps(meta, indent=1))
    return dst


def _proc(pid: int) -> tuple[float, int, int] | None:
    """``(RSS MiB, open descriptors, threads)`` of process ``pid``, or None when it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    if "VmRSS" not in fields:  # exiting (a zombie has no memory)
        return None
    return int(fields["VmRSS"].split()[0]) / 1024.0, fds, int(fields["Threads"])


def _done(journal: Path) -> int:
    try:
        with open(journal, "rb") as fh:
            return max(0, sum(1 for _ in fh) - 1)
    except FileNotFoundError:
        return -1


def measure(seq: Path, out: Path, extra: list[str], log: Path | None = None) -> tuple[list[tuple], float, int, str]:
    """Run ``vio-depth run`` on ``seq`` and sample it: ``(samples, seconds, exit code, stderr)``;
    samples are ``(seconds, frames done, RSS MiB, descriptors, threads)``, also appended to
    ``log`` (CSV) as they come."""
    journal = out.parent / f".{out.name}.vio-depth-partial" / "journal.jsonl"
    cmd = [sys.executable, "-m", "vio_depth.cli", "run", str(seq), "--out", str(out), "--no-progress", *extra]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    samples = []
    sink = open(log, "w") if log is not None else None
    try:
        while proc.poll() is None:
            s = _proc(proc.pid)
            if s is not None:
                samples.append((time.monotonic() - t0, _done(journal), *s))
                if sink is not None:
                    sink.write(",".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in samples[-1]) + "\n")
                    sink.flush()
            time.sleep(0.25)
    finally:
        if sink is not None:
            sink.close()
    err = proc.stderr.read()
    return samples, time.monotonic() - t0, proc.returncode, err


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--workdir", default=None, help="keep the sequence and output here (default: a temporary folder)")
    ap.add_argument("--samples", default=None, metavar="CSV",
                    help="also write every sample (seconds, frames done, RSS MiB, fds, threads) to this file")
    ap.add_argument("run_args", nargs="*", help="more `vio-depth run` flags (after --)")
    args = ap.parse_args(argv)
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="vio-depth-long-"))
    try:
        seq = build_sequence(work / "seq", args.frames)
        samples, seconds, rc, err = measure(seq, work / "out", args.run_args,
                                            None if args.samples is None else Path(args.samples))
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    print(f"vio-depth run, {args.frames} frames (street sample ping-ponged, 640x256, SIMULATED disparity), "
          f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}: "
          f"exit {rc} in {seconds:.0f} s ({args.frames / seconds:.1f} frames/s)")
    if rc != 0:
        print(err)
        return 1
    running = [s for s in samples if s[1] >= 0]
    print(f"{'frames done':>11} {'seconds':>8} {'RSS MiB':>8} {'open fds':>8} {'threads':>7}")
    for q in range(1, 11):
        target = args.frames * q // 10
        row = next((s for s in running if s[1] >= target - 1), running[-1])
        print(f"{row[1]:>11} {row[0]:>8.0f} {row[2]:>8.0f} {row[3]:>8} {row[4]:>7}")
    end = samples[-1]
    print(f"{'end':>11} {end[0]:>8.0f} {end[2]:>8.0f} {end[3]:>8} {end[4]:>7}   (run-end outputs, backward pass)")
    base = next((s for s in running if s[1] >= min(BASELINE_FRAME, args.frames) - 1), running[0])
    peak_rss = max(s[2] for s in samples)
    peak_fds = max(s[3] for s in samples)
    ok_rss = peak_rss <= 1.1 * base[2] + 64
    ok_fds = peak_fds <= base[3] + 8
    print(f"baseline (frame {base[1]}): RSS {base[2]:.0f} MiB, {base[3]} fds; "
          f"peak RSS {peak_rss:.0f} MiB ({peak_rss / base[2]:.2f} x) {'ok' if ok_rss else 'FAIL'} "
          f"(<= 1.1 x + 64 MiB); peak fds {peak_fds} {'ok' if ok_fds else 'FAIL'} (<= baseline + 8)")
    return 0 if ok_rss and ok_fds else 1


if __name__ == "__main__":
    sys.exit(main())
