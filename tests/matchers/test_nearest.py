"""matchers.nearest: the bfloat16 screen + exact re-ranking gives the float32 backend's
nearest neighbours, similarities and matches bit for bit, on constructed near-ties and on
real SIFT descriptors;
its error bound holds for torch's arithmetic on this machine; backend choice and errors."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
skdata = pytest.importorskip("skimage.data")

from matchers import nearest  # noqa: E402
from matchers.nearest import BF16_RELATIVE_ERROR, nearest_two_rows, resolve_backend  # noqa: E402
from matchers.sift import SiftMatcher, SiftSettings, normalize_descriptors, ratio_match  # noqa: E402
from vio_core.errors import SettingsError, ShapeError  # noqa: E402

needs_torch = pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="torch not installed")

KITTI_IMAGES = (Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti_tiny" / "2011_09_26"
                / "2011_09_26_drive_0023_sync" / "image_02" / "data")


@pytest.fixture(scope="module")
def real_descriptors():
    """SIFT descriptors (RootSIFT) of two real photos: KITTI frames 0 and 2 when
    ../shared/data is present (4 000 each), else the astronaut and a warped copy."""
    m = SiftMatcher(SiftSettings(nearest_backend="float32"))
    files = sorted(KITTI_IMAGES.glob("*.png"))
    if len(files) >= 3:
        imgs = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in (files[0], files[2])]
    else:
        img = skdata.astronaut()
        h = np.array([[0.95, -0.1, 30.0], [0.1, 0.95, -10.0], [1e-4, 0.0, 1.0]])
        imgs = [img, cv2.warpPerspective(img, h, (img.shape[1], img.shape[0]))]
    fa, fb = (m.extract(i) for i in imgs)
    assert len(fa) > 500 and len(fb) > 500
    return fa.descriptors, fb.descriptors


def near_ties(n_rows: int, n_cols: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Non-negative unit rows where every row of x has several columns of y whose
    similarities are within 1e-4..1e-2 of its best (closer than the screen's error bound
    of ~0.01), and exact ties (duplicated columns)."""
    rng = np.random.default_rng(seed)
    y = rng.random((n_cols, 128)) * 255
    base = rng.integers(0, n_cols, n_rows)
    x = normalize_descriptors(y[base] + rng.random((n_rows, 128)) * 20)
    # 3 perturbed copies of each row's base column, and exact copies of 50 columns
    near = [y[base[: n_cols // 3]] + rng.random((n_cols // 3, 128)) * s for s in (5.0, 10.0, 20.0)]
    y = normalize_descriptors(np.concatenate([y, *near, y[:50]]))
    return x, y


def exact_nearest_two(x, y):
    """Best index (lowest among exact ties) and best/second similarity in float64."""
    s = x.astype(np.float64) @ y.T.astype(np.float64)
    nn = s.argmax(axis=1)
    top = np.sort(s, axis=1)[:, -2:][:, ::-1]
    return nn, top


@needs_torch
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bfloat16_screen_gives_the_exact_nearest_two_on_near_ties(seed):
    x, y = near_ties(700, 900, seed)
    nn64, s64 = exact_nearest_two(x, y)
    gap = s64[:, 0] - s64[:, 1]
    assert (gap < 0.005).mean() > 0.3 and (gap == 0).sum() > 5  # the screen alone cannot decide these
    decidable = (gap == 0) | (gap > 1e-6)  # not decided by float32 rounding
    torch = pytest.importorskip("torch")
    naive = (torch.from_numpy(x).bfloat16() @ torch.from_numpy(y).bfloat16().T).float().numpy().argmax(axis=1)
    assert (naive != nn64).sum() > 10  # bfloat16 alone picks wrong neighbours here
    for block in (2048, 128, 7):
        nn32, s32 = nearest_two_rows(x, y, block, "float32")
        nn16, s16 = nearest_two_rows(x, y, block, "bfloat16")
        np.testing.assert_array_equal(nn32[decidable], nn64[decidable])  # exact ties: the lower column
        np.testing.assert_allclose(s32, s64, rtol=0, atol=1e-7)  # the float64 value rounded once
        # both backends re-rank their candidates with the same exact formula: bit for bit
        np.testing.assert_array_equal(nn16, nn32)
        assert s16.tobytes() == s32.tobytes()


@needs_torch
def test_bfloat16_matches_equal_float32_matches_on_real_descriptors(real_descriptors):
    a, b = real_descriptors
    for args in ((0.8, True), (0.8, False), (1.0, True), (0.6, True)):
        m32 = ratio_match(a, b, *args, backend="float32")
        m16 = ratio_match(a, b, *args, backend="bfloat16")
        assert len(m32) > 50
        np.testing.assert_array_equal(m16.idx_a, m32.idx_a)
        np.testing.assert_array_equal(m16.idx_b, m32.idx_b)
        assert m16.confidence.tobytes() == m32.confidence.tobytes()


@needs_torch
def test_the_screens_error_bound_holds_for_torch_on_this_machine(real_descriptors):
    """The screen is exact only if torch's bfloat16 product stays within BF16_RELATIVE_ERROR
    of the float32 similarity (bfloat16 inputs, float32 sums, one rounding of the output)."""
    torch = pytest.importorskip("torch")
    a, b = real_descriptors
    exact = a.astype(np.float64) @ b.T.astype(np.float64)
    screen = (torch.from_numpy(a).bfloat16() @ torch.from_numpy(b).bfloat16().T).float().numpy()
    rel = np.abs(screen - exact) / np.maximum(exact, 1e-12)
    assert rel[exact > 1e-3].max() <= BF16_RELATIVE_ERROR
    assert rel[exact > 1e-3].max() > 1e-4  # it really was computed in bfloat16


@needs_torch
def test_rows_the_keep_filter_rejects_are_skipped():
    x, y = near_ties(300, 400, 5)
    nn32, s32 = nearest_two_rows(x, y, backend="float32")
    keep_even = lambda s1_max, s2_min: np.arange(len(s1_max)) % 2 == 0  # noqa: E731
    nn, s = nearest_two_rows(x, y, 64, "bfloat16", keep=keep_even)
    np.testing.assert_array_equal(nn[::2], nn32[::2])
    assert s[::2].tobytes() == s32[::2].tobytes()
    assert np.isnan(s[1::2]).all()


def test_negative_descriptors_use_float32_whatever_the_backend():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(50, 16)).astype(np.float32)
    y = rng.normal(size=(60, 16)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    nn32, s32 = nearest_two_rows(x, y, backend="float32")
    nn, s = nearest_two_rows(x, y, backend="auto")
    np.testing.assert_array_equal(nn, nn32)
    assert s.tobytes() == s32.tobytes()


def test_backend_names_and_auto(monkeypatch):
    with pytest.raises(SettingsError, match="valid: auto, float32, bfloat16"):
        resolve_backend("bf16")
    with pytest.raises(SettingsError, match="nearest_backend 'fast'"):
        SiftSettings(nearest_backend="fast")
    assert resolve_backend("float32") == "float32"
    assert resolve_backend("auto") in ("float32", "bfloat16")
    large = "bfloat16" if nearest.bfloat16_is_native() else "float32"
    assert resolve_backend("auto", 1500, 1500) == "float32"  # the rendered samples: not worth importing torch
    assert resolve_backend("auto", 2000, 2000) == "float32"  # real indoor 640x480 images: at most ~2 000
    assert resolve_backend("auto", 4000, 4000) == large  # real 1242x375 images
    assert resolve_backend("auto", 1300, 4000) == large  # the reverse direction of their matching
    assert resolve_backend("auto", 100, 4000) == "float32"  # a small product
    assert resolve_backend("bfloat16", 10, 10) == "bfloat16"  # asked for by name: kept
    monkeypatch.setattr(nearest.importlib.util, "find_spec", lambda name: None)  # torch not installed
    assert resolve_backend("auto") == "float32"


def test_shape_errors():
    x = np.ones((3, 8), np.float32) / np.sqrt(8)
    with pytest.raises(ShapeError, match="at least 2 rows"):
        nearest_two_rows(x, x[:1])
    with pytest.raises(ShapeError, match="y: expected shape"):
        nearest_two_rows(x, np.ones((3, 9), np.float32))


def test_small_products_do_not_import_torch():
    """Matching ~1 000 x 1 000 descriptors (the rendered samples) never pays for importing torch."""
    code = (
        "import sys, numpy as np\n"
        "from matchers import create_matcher\n"
        "from matchers.sift import normalize_descriptors\n"
        "from matchers.base import Features\n"
        "rng = np.random.default_rng(0)\n"
        "f = [Features(rng.random((1000, 2), np.float32) * 500, normalize_descriptors(rng.random((1000, 128)) * 255),\n"
        "              np.ones(1000, np.float32), (640, 480)) for _ in range(2)]\n"
        "m = create_matcher('sift').match(f[0], f[1])\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.stdout.strip() == "False", out.stderr


@needs_torch
def test_an_older_torch_without_the_cpu_checks_means_float32(monkeypatch):
    torch = pytest.importorskip("torch")
    for name in ("_is_amx_tile_supported", "_is_avx512_bf16_supported"):
        monkeypatch.delattr(torch.cpu, name, raising=False)
    nearest._cpu_has_bfloat16.cache_clear()
    try:
        assert resolve_backend("auto", 4000, 4000) == "float32"
    finally:
        monkeypatch.undo()
        nearest._cpu_has_bfloat16.cache_clear()


@needs_torch
def test_the_bfloat16_product_runs_on_one_thread_of_the_caller_only(monkeypatch):
    """torch's pool spins after each product beside the next stages (a FrameStream's matching
    2.5x slower on 2 cores): the product runs on one OpenMP thread, set for the calling
    thread only and restored afterwards."""
    import threading

    torch = pytest.importorskip("torch")
    x, y = near_ties(300, 400, 0)
    before = torch.get_num_threads()
    if before < 2:
        torch.set_num_threads(2)
    try:
        seen, elsewhere = [], []
        mm = torch.mm

        def spy(*args, **kwargs):
            seen.append(torch.get_num_threads())
            other = threading.Thread(target=lambda: elsewhere.append(torch.get_num_threads()))
            other.start()
            other.join()
            return mm(*args, **kwargs)

        monkeypatch.setattr(torch, "mm", spy)
        nn16, s16 = nearest_two_rows(x, y, 128, "bfloat16")
        assert seen and set(seen) == {1}
        assert set(elsewhere) == {torch.get_num_threads()} and torch.get_num_threads() >= 2  # restored
        nn32, s32 = nearest_two_rows(x, y, 128, "float32")
        np.testing.assert_array_equal(nn16, nn32)
    finally:
        torch.set_num_threads(before)
