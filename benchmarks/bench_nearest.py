"""SIFT descriptor matching: the float32 and bfloat16 nearest-neighbour backends side by side.

``matchers.sift.ratio_match`` (ratio test + mutual check, both directions) on RootSIFT
descriptors of two real KITTI-tiny frames (frames 0 and 2; without ``../shared/data``: the
street sample's first and third frames rendered at 1242x375, SIMULATED scene), cut to N
descriptors each, one thread (OpenBLAS and torch limited to 1, as in an overlapped run),
best of ``--repeats``. Every row asserts that both backends gave the same matches and
confidences bit for bit, and counts the bfloat16 screen's candidates per row.

    python benchmarks/bench_nearest.py
    python benchmarks/bench_nearest.py --sizes 1000 4000 --repeats 20
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]  # measure this checkout's code

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from matchers import SiftMatcher, SiftSettings  # noqa: E402
from matchers.nearest import BF16_RELATIVE_ERROR, bfloat16_is_native  # noqa: E402
from matchers.sift import ratio_match  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti_tiny" / "2011_09_26" / "2011_09_26_drive_0023_sync" / "image_02" / "data"
STREET = ROOT / "sample_sequences" / "street" / "images"


def descriptor_pair() -> tuple[str, np.ndarray, np.ndarray]:
    files = sorted(KITTI.glob("*.png"))
    name = "KITTI-tiny frames 0 and 2 (real)"
    if len(files) < 3:
        files = sorted(STREET.glob("*.png"))
        name = "street sample frames 0 and 2 upscaled to 1242x375 (rendered)"
    m = SiftMatcher(SiftSettings(nearest_backend="float32"))
    feats = []
    for f in (files[0], files[2]):
        img = cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)
        if img.shape[:2] != (375, 1242):
            img = cv2.resize(img, (1242, 375), interpolation=cv2.INTER_CUBIC)
        feats.append(m.extract(img))
    return name, feats[0].descriptors, feats[1].descriptors


def best_ms(fn, repeats: int) -> float:
    fn()  # warm-up: oneDNN compiles a kernel per new shape
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * min(times)


def screen_candidates(a: np.ndarray, b: np.ndarray) -> float:
    """Mean candidates per row of the bfloat16 screen (a -> b, before the ratio-test filter)."""
    import torch

    s = (torch.from_numpy(a).bfloat16() @ torch.from_numpy(b).bfloat16().T).float().numpy()
    second = np.sort(s, axis=1)[:, -2]
    floor = second * (1 - BF16_RELATIVE_ERROR) / (1 + BF16_RELATIVE_ERROR)
    return float((s >= floor[:, None]).sum(axis=1).mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[1000, 1500, 2000, 2500, 3000, 4000])
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args(argv)
    if not bfloat16_is_native():
        print("bench_nearest: this CPU (or this install) has no native bfloat16: only float32 would be used")
        return 0
    import torch

    name, a_all, b_all = descriptor_pair()
    print(f"bench_nearest: {name}, {len(a_all)} and {len(b_all)} descriptors; one thread; best of {args.repeats}")
    print("| descriptors per image | float32 ms | bfloat16 ms | float32 / bfloat16 | matches | screen candidates per row |")
    print("|---|---|---|---|---|---|")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpool_limits(1, user_api="blas"):
            for n in args.sizes:
                a, b = a_all[:n], b_all[:n]
                m32, m16 = ratio_match(a, b, backend="float32"), ratio_match(a, b, backend="bfloat16")
                assert np.array_equal(m32.idx_a, m16.idx_a) and np.array_equal(m32.idx_b, m16.idx_b)
                assert m32.confidence.tobytes() == m16.confidence.tobytes()
                t32 = best_ms(lambda: ratio_match(a, b, backend="float32"), args.repeats)
                t16 = best_ms(lambda: ratio_match(a, b, backend="bfloat16"), args.repeats)
                print(f"| {len(a)} | {t32:.1f} | {t16:.1f} | {t32 / t16:.2f} | {len(m32)} | "
                      f"{screen_candidates(a, b):.1f} |")
    finally:
        torch.set_num_threads(before)
    return 0


if __name__ == "__main__":
    sys.exit(main())
