"""Streaming ROS bags: peak memory of opening a bag and reading every frame does not grow with its length.

For each bag kind (ROS 1 ``.bag``, ROS 2 SQLite3, ROS 2 MCAP; written by ``rosbags``' writers
through :class:`vio_depth.io.bag_writer.BagWriter`), two bags of the same stream:

* **short** (the baseline): 200 images and 1 000 IMU messages;
* **long**: 2 000 images and 10 000 IMU messages (the issue's figure),

with EuRoC-sized raw ``mono8`` images (752 x 480, 361 KB each: the long bag holds 722 MB of
pixels), a ``CameraInfo`` per image and a 100 Hz ``sensor_msgs/Imu`` stream. Each bag is
measured in its own subprocess: :func:`vio_depth.io.open_bag` (one pass through the bag,
keeping per image only its stamps, and the IMU samples), then every frame's ``image()`` in order (each read
from the bag again, as a run reads them), then the peak RSS (``VmHWM``). Memory is flat when
the long bag's peak stays within ``--max-growth-mb`` (default 32 MB) of the short bag's;
the script exits 1 otherwise.

    python benchmarks/bench_bag.py                      # ~2.3 GB of temporary bags, a few minutes
    python benchmarks/bench_bag.py --kinds mcap --long 1000
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_depth.io.bag_writer import BAG_KINDS, BagWriter

CAMERA = Camera(752, 480, 458.654, 457.296, 367.215, 248.375)
IMU_PER_IMAGE = 5  # 100 Hz IMU, 20 Hz camera
T0 = 1_600_000_000 * 10**9


def write_bag(path: Path, kind: str, n_images: int) -> Path:
    """A bag of ``n_images`` 752x480 mono8 images at 20 Hz with camera info and a 100 Hz IMU."""
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (CAMERA.height, CAMERA.width + 64), dtype=np.uint8)
    with BagWriter(path, kind) as w:
        m = w.messages
        for i in range(n_images):
            t = T0 + i * 50_000_000
            for k in range(IMU_PER_IMAGE):
                s = t + k * 10_000_000
                w.write("/imu0", m.imu(s, "imu0", rng.normal(0, 0.01, 3), [0.0, 0.0, 9.81] + rng.normal(0, 0.05, 3)))
            w.write("/cam0/image_raw", m.image(t, "cam0", np.ascontiguousarray(base[:, i % 64:i % 64 + CAMERA.width]),
                                               "mono8"))
            w.write("/cam0/camera_info", m.camera_info(t, "cam0", CAMERA))
    return path


def measure(path: str) -> dict:
    """In this (fresh) process: open the bag, read every frame's image; timings and peak RSS."""
    from vio_depth.io import BagSettings, Calibration, open_bag
    from vio_depth.io.kalibr import KalibrCamera, KalibrImu

    calib = Calibration(KalibrCamera("cam0", CAMERA, np.eye(4)), KalibrImu(1.7e-4, 2e-5, 2e-3, 3e-3))
    t = time.perf_counter()
    bag = open_bag(path, BagSettings(pose_topic="none", calibration=calib))  # the IMU is read too
    opened = time.perf_counter() - t
    rss_open = _vm("VmHWM")
    t = time.perf_counter()
    checksum = 0
    for frame in bag:
        checksum += int(frame.image()[240, 376, 0])
    read = time.perf_counter() - t
    return {"frames": len(bag), "imu": len(bag.imu.t),
            "open_s": opened, "read_ms_per_frame": 1000 * read / len(bag), "peak_after_open_mb": rss_open,
            "peak_mb": _vm("VmHWM"), "checksum": checksum}


def _vm(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=list(BAG_KINDS), choices=BAG_KINDS)
    ap.add_argument("--short", type=int, default=200, help="images of the baseline bag")
    ap.add_argument("--long", type=int, default=2000, help="images of the long bag")
    ap.add_argument("--max-growth-mb", type=float, default=32.0)
    ap.add_argument("--measure", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return 0
    rows, ok = [], True
    with tempfile.TemporaryDirectory(prefix="bench_bag_") as tmp:
        for kind in args.kinds:
            result = {}
            for label, n in (("short", args.short), ("long", args.long)):
                path = Path(tmp) / (f"{kind}_{n}.bag" if kind == "ros1" else f"{kind}_{n}")
                t = time.perf_counter()
                write_bag(path, kind, n)
                written = time.perf_counter() - t
                out = subprocess.run([sys.executable, __file__, "--measure", str(path)], capture_output=True,
                                     text=True, check=True)
                result[label] = dict(json.loads(out.stdout), size_mb=_size_mb(path), write_s=written)
                shutil.rmtree(path) if path.is_dir() else path.unlink()
            growth = result["long"]["peak_mb"] - result["short"]["peak_mb"]
            ok &= growth <= args.max_growth_mb
            rows.append((kind, result, growth))
    print(f"{'bag':6s} {'images':>6s} {'IMU':>6s} {'bag MB':>7s} {'open s':>7s} {'read ms/img':>11s} "
          f"{'peak RSS MB':>11s}  vs short (baseline)")
    for kind, result, growth in rows:
        for label in ("short", "long"):
            r = result[label]
            ratio = r["peak_mb"] / result["short"]["peak_mb"]
            extra = "baseline" if label == "short" else f"{growth:+.1f} MB ({ratio:.3f} x)"
            print(f"{kind:6s} {r['frames']:6d} {r['imu']:6d} {r['size_mb']:7.0f} {r['open_s']:7.2f} "
                  f"{r['read_ms_per_frame']:11.2f} {r['peak_mb']:11.1f}  {extra}")
    print(f"memory flat (long - short <= {args.max_growth_mb:g} MB for every kind): {'yes' if ok else 'NO'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
