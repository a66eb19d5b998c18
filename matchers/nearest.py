"""The two nearest neighbours of unit-norm descriptors, exactly, two ways.

For every row ``x[i]`` the most similar row of ``y`` and the best and second-best
similarities ``x[i] . y[j]`` (cosine similarities: the rows have unit L2 norm, so the
Euclidean distance is ``sqrt(2 - 2 s)``). This is the whole cost of SIFT matching: with
4 000 descriptors per image it is a 4 000 x 4 000 x 128 matrix product per direction.

Both backends find a few candidate columns per row with a fast product whose error is
bounded, then compute the candidates' similarities exactly (products summed in float64,
rounded once to float32) and keep the two best. A column can be among the true two best
only if the upper bound of its similarity reaches the second largest lower bound, so the
candidates always hold the true two best, and both backends give **the same answer, bit
for bit** (ties go to the lower column, like ``argmax``). Rows whose ratio test cannot pass
even with the bounds may be skipped (``keep``).

``"float32"``
    numpy's float32 matrix product in blocks of rows (error below ``129 * 2**-24`` for
    unit vectors: usually only the best two are candidates). Always available; about
    34 ms per 4 000 x 4 000 product on one core of the development machine (OpenBLAS).

``"bfloat16"``
    the product in bfloat16 (torch; oneDNN runs it on AMX/AVX512-BF16 tiles, about 3 ms for
    the same product). Rounding the inputs and the output to bfloat16 (8 significant bits,
    unit roundoff ``u = 2**-8``) and summing in float32 changes a sum of **non-negative**
    products by a relative error below ``theta = 3u + 3u**2 + 128 * 2**-24`` (about
    0.0118): every true similarity lies in ``[s_hat / (1 + theta), s_hat / (1 - theta)]``.
    On real SIFT descriptors (KITTI) that leaves about 10 candidates per row. It needs
    non-negative descriptors (SIFT and RootSIFT are; others fall back to float32) and a
    CPU with native bfloat16 arithmetic: elsewhere bfloat16 is emulated and slower than
    float32, so ``"auto"`` picks it only where it pays, and only for large products
    (:func:`resolve_backend`).

The tests check the bound against torch's arithmetic on real descriptors, and both backends
against each other and against float64 on constructed near-ties.
"""

from __future__ import annotations

import functools
import importlib.util
import threading
from collections.abc import Callable

import numpy as np
from threadpoolctl import ThreadpoolController

from vio_core.checks import check_array
from vio_core.errors import SettingsError, ShapeError

#: the backends of :func:`nearest_two_rows` (``"auto"`` picks one of the others)
NEAREST_BACKENDS = ("auto", "float32", "bfloat16")

#: relative error bound of a bfloat16 similarity of non-negative unit vectors (see above)
_U = 2.0**-8
BF16_RELATIVE_ERROR = 3 * _U + 3 * _U**2 + 128 * 2.0**-24


def _torch():
    """torch, imported where the bfloat16 backend is used (an optional heavy dependency)."""
    import torch

    return torch


@functools.cache
def _openmp_pools():
    """threadpoolctl's handle on the OpenMP runtimes loaded (torch's), looked up once after
    torch is imported (a lookup costs about 0.5 ms; limiting through the handle 0.01 ms)."""
    _torch()
    return ThreadpoolController().select(user_api="openmp")


def _one_openmp_thread():
    """The bfloat16 product on one thread: OpenMP's thread count is a setting of the calling
    thread (``omp_set_num_threads``), restored on exit, so no other thread is affected.

    With torch's default pool (one thread per core) the product itself is barely faster on
    2 cores (one 4 000 x 4 000 ratio match 22 against 25 ms), but the pool's threads spin after
    it while this thread reduces the screen and the next stages run: a ``FrameStream`` on 20
    KITTI-tiny frames matched in 284-302 ms per frame with torch's 2 threads, in 110-117 ms
    with one (2 cores, load average 5-6, interleaved runs). The overlapped CLI run already
    limits torch to one thread (``run.overlap.TorchThreads``)."""
    return _openmp_pools().limit(limits=1)


def bfloat16_is_native() -> bool:
    """True when torch is installed and this CPU computes bfloat16 products natively
    (AMX tiles or AVX512-BF16); without torch nothing is imported and the answer is False."""
    return importlib.util.find_spec("torch") is not None and _cpu_has_bfloat16()


@functools.cache
def _cpu_has_bfloat16() -> bool:
    cpu = _torch().cpu  # the checks are private torch API: absent (older torch) means "no"
    checks = (getattr(cpu, name, None) for name in ("_is_amx_tile_supported", "_is_avx512_bf16_supported"))
    return any(bool(check()) for check in checks if check is not None)


#: ``"auto"``'s speed policy (every backend gives the same result, so it changes no output).
#: ``python benchmarks/bench_nearest.py`` (development machine, one thread as in an
#: overlapped run, real KITTI descriptors), ms per ratio match float32 / bfloat16:
#: 1 000 x 1 000 3.2 / 2.2, 2 000 x 2 000 13.5 / 6.5, 4 000 x 4 000 58.7 / 24.3.
#: Importing torch costs about 1 s and 200 MB of memory once per process, so the screen is
#: used only where one side has at least :data:`AUTO_MIN_DESCRIPTORS` descriptors, i.e.
#: images that fill most of the default 4 000 features (real KITTI 1242x375 frames: 4 000),
#: and the product has at least :data:`AUTO_MIN_PRODUCT` similarities. Real indoor frames
#: stay on float32 without importing torch (7-Scenes 640x480: median 1 066 features, at
#: most 2 045; EuRoC 752x480: about 930), as do the rendered samples (street at 1242x375:
#: at most ~2 000). The rule depends only on the sizes, never on what the process imported.
AUTO_MIN_DESCRIPTORS = 3000
AUTO_MIN_PRODUCT = 1200 * 1200


def resolve_backend(backend: str, n_x: int | None = None, n_y: int | None = None) -> str:
    """The backend that compares ``n_x`` with ``n_y`` descriptors (None: a large product).

    ``"auto"`` is ``"bfloat16"`` where bfloat16 is native (torch installed, CPU with
    AMX/AVX512-BF16) and the product is large enough (:data:`AUTO_MIN_DESCRIPTORS`,
    :data:`AUTO_MIN_PRODUCT`), else ``"float32"``; the other names are kept. Unknown names
    raise :class:`SettingsError` listing the valid ones.
    """
    if backend not in NEAREST_BACKENDS:
        raise SettingsError(f"unknown nearest-neighbour backend {backend!r}; valid: {', '.join(NEAREST_BACKENDS)}")
    if backend != "auto":
        return backend
    if n_x is not None and n_y is not None and (
            max(n_x, n_y) < AUTO_MIN_DESCRIPTORS or n_x * n_y < AUTO_MIN_PRODUCT):
        return "float32"
    return "bfloat16" if bfloat16_is_native() else "float32"


# ----------------------------------------------------------------------------- common
def _round_up(n: int, quantum: int) -> int:
    return -(-n // quantum) * quantum


def _two_best_of_block(screen, lowest, to_float, bounds, floor_of, x_block, y, keep, nn, sims, offset):
    """The exact two best of each row of one block of a screen (see the module docstring).

    ``screen (n, >= Ny)``: values that order like the similarities (padding columns below
    every similarity); ``lowest``: a screen value below every similarity; ``to_float``: screen values -> float32 estimates; ``bounds(est) ->
    (lower, upper)`` of the true similarity; ``floor_of(v)``: the smallest screen value
    whose upper bound reaches ``v`` (rounded down). Writes rows ``offset + i`` of ``nn``
    and ``sims``; rows ``keep`` rejects are left as they are.
    """
    n = len(screen)
    rows = np.arange(n)
    best = screen.argmax(axis=1)
    top = screen[rows, best]
    screen[rows, best] = lowest
    _, s1_high = bounds(to_float(top))
    s2_low, _ = bounds(to_float(screen.max(axis=1)))
    screen[rows, best] = top  # the best is a candidate again
    r = np.arange(n) if keep is None else np.flatnonzero(keep(s1_high, s2_low))
    if len(r) == 0:
        return
    # a column can be among the true two best only if its upper bound reaches the second
    # largest lower bound; flatnonzero: much faster than a 2-d nonzero on a sparse mask
    floor = floor_of(s2_low[r])
    cand_r, cand_c = np.divmod(np.flatnonzero(screen[r] >= floor[:, None]), screen.shape[1])
    # exact similarities of the candidates (summed in float64, rounded once to float32: the
    # same value whichever screen found the candidate), grouped by row, columns ascending;
    # then the two best per row, ties to the lower column like argmax
    exact = np.einsum("ij,ij->i", x_block[r[cand_r]], y[cand_c], dtype=np.float64).astype(np.float32)
    new_row = np.r_[True, cand_r[1:] != cand_r[:-1]]
    first = np.flatnonzero(new_row)
    group = np.cumsum(new_row) - 1
    best1 = np.maximum.reduceat(exact, first)
    at_best = np.flatnonzero(exact == best1[group])
    at_best = at_best[np.r_[True, group[at_best][1:] != group[at_best][:-1]]]
    exact[at_best] = -np.inf
    rows_out = offset + r[cand_r[first]]
    nn[rows_out] = cand_c[at_best]
    sims[rows_out, 0] = best1
    sims[rows_out, 1] = np.maximum.reduceat(exact, first)  # every kept row has >= 2 candidates


# ----------------------------------------------------------------------------- float32
#: absolute error bound of a float32 dot product of 128-d unit vectors (128 products and
#: sums, each rounded once: at most 129 * 2**-24 * |x| |y|), with a margin
_F32_ABSOLUTE_ERROR = 2 * 129 * 2.0**-24


def _nearest_two_float32(x: np.ndarray, y: np.ndarray, block_rows: int, keep, nn, sims):
    scale = np.float32(_F32_ABSOLUTE_ERROR * x.shape[1] / 128
                       * np.sqrt(np.einsum("ij,ij->i", x, x).max()) * np.sqrt(np.einsum("ij,ij->i", y, y).max()))

    def bounds(est):
        return est - scale, est + scale

    def floor_of(v):
        return v - scale

    for start in range(0, len(x), block_rows):
        xb = x[start:start + block_rows]
        _two_best_of_block(xb @ y.T, -np.inf, lambda v: v, bounds, floor_of, xb, y, keep, nn, sims, start)


# ----------------------------------------------------------------------------- bfloat16 screen
def _bf16_bits_to_float(bits: np.ndarray) -> np.ndarray:
    """float32 values of bfloat16 bit patterns held as int16."""
    return (bits.astype(np.uint16).astype(np.uint32) << 16).view(np.float32)


def _float_to_bf16_floor_bits(values: np.ndarray) -> np.ndarray:
    """int16 bit pattern of the largest bfloat16 <= ``values`` (non-negative float32)."""
    return (np.asarray(values, np.float32).view(np.uint32) >> 16).astype(np.uint16).view(np.int16)


_LOCAL = threading.local()  # per thread: the reused bfloat16 similarity buffer


def _similarity_buffer(size: int):
    """A flat torch bfloat16 buffer of at least ``size`` elements, kept per thread:
    a fresh 16 MB block per call costs more in page faults than the product itself."""
    torch = _torch()
    buf = getattr(_LOCAL, "buf", None)
    if buf is None or buf.numel() < size:
        buf = _LOCAL.buf = torch.empty(size, dtype=torch.bfloat16)
    return buf


#: the bfloat16 products' shapes are rounded up to these multiples (rows of x, rows of y):
#: oneDNN compiles a kernel per new shape (~8 ms, more than the product), so feature counts
#: that change from frame to frame must map onto a few shapes
_ROW_QUANTUM, _COL_QUANTUM = 512, 256


def _padded_bfloat16(a: np.ndarray, rows: int):
    """``a`` as a torch bfloat16 tensor of ``rows`` rows (zeros below)."""
    torch = _torch()
    out = torch.zeros((rows, a.shape[1]), dtype=torch.bfloat16)
    out[: len(a)] = torch.from_numpy(a)
    return out


def _nearest_two_bfloat16(x: np.ndarray, y: np.ndarray, block_rows: int, keep, nn, sims):
    torch = _torch()
    block = min(_round_up(block_rows, _ROW_QUANTUM), _round_up(len(x), _ROW_QUANTUM))
    ny = _round_up(len(y), _COL_QUANTUM)
    x16 = _padded_bfloat16(x, _round_up(len(x), block))
    y16 = _padded_bfloat16(y, ny)
    # the bounds widened by 2**-20 so that their own float32 rounding cannot narrow them
    lo, hi = (1.0 - 2.0**-20) / (1.0 + BF16_RELATIVE_ERROR), (1.0 + 2.0**-20) / (1.0 - BF16_RELATIVE_ERROR)

    def bounds(est):
        return est * np.float32(lo), est * np.float32(hi)

    def floor_of(v):
        return _float_to_bf16_floor_bits(v * np.float32(1.0 / hi))

    out = _similarity_buffer(block * ny)[: block * ny].view(block, ny)
    with _one_openmp_thread():
        for start in range(0, len(x), block):
            n = min(block, len(x) - start)
            torch.mm(x16[start:start + block], y16.T, out=out)
            # non-negative bfloat16 values order like their bit patterns read as int16; the
            # padding columns get -1 (below every similarity) and the padding rows are dropped
            bits = out.view(torch.int16).numpy()[:n]
            bits[:, len(y):] = -1
            _two_best_of_block(bits, -1, _bf16_bits_to_float, bounds, floor_of, x[start:start + n], y, keep, nn,
                               sims, start)


def nearest_two_rows(
    x,
    y,
    block_rows: int = 2048,
    backend: str = "float32",
    keep: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
):
    """For every row of ``x``: the index of the most similar row of ``y`` and the best and
    second-best similarities.

    Args:
        x: (Nx, D) float32 descriptors, unit L2 norm (non-negative for ``"bfloat16"``).
        y: (Ny, D) float32 descriptors, unit L2 norm; Ny >= 2.
        block_rows: rows of ``x`` compared at once (memory about ``block_rows * Ny * 4``
            bytes).
        backend: ``"float32"``, ``"bfloat16"`` or ``"auto"`` (see the module docstring).
        keep: optional filter ``keep(s1_max, s2_min) -> (rows,) bool`` given an upper bound
            of each row's best similarity and a lower bound of its second best; rows it
            rejects may be skipped (their outputs are then ``nn = 0``, similarities NaN).
            It must reject only rows the caller discards whatever their exact values.

    Returns:
        ``(nn, sims)``: ``nn (Nx,)`` int64, ``sims (Nx, 2)`` float32 best and second best.
    """
    x = np.ascontiguousarray(check_array("x", x, (None, None), dtype=np.float32))
    y = np.ascontiguousarray(check_array("y", y, (None, x.shape[1]), dtype=np.float32))
    if len(y) < 2:
        raise ShapeError(f"nearest_two_rows needs at least 2 rows in y, got {len(y)}")
    backend = resolve_backend(backend, len(x), len(y))
    if backend == "bfloat16" and len(x) and (x.min() < 0 or y.min() < 0):
        backend = "float32"  # the screen's error bound needs non-negative products
    nn = np.zeros(len(x), np.int64)
    sims = np.full((len(x), 2), np.nan, np.float32)
    if len(x) == 0:
        return nn, sims
    run = _nearest_two_bfloat16 if backend == "bfloat16" else _nearest_two_float32
    run(x, y, block_rows, keep, nn, sims)
    return nn, sims
