"""Issue 12, case 6 of "What to build": property-based tests of every loader.

For each format (native, KITTI raw, 7-Scenes, TUM RGB-D, ASL / EuRoC) a small valid sequence folder is
built once; hypothesis then generates :data:`EXAMPLES` (1 000) damaged copies of it, each
with one to three mutations of its files (bytes replaced, truncated or flipped, a text line
replaced by generated text or numbers such as ``nan``, ``1e308`` and non-ASCII, a line
inserted or duplicated, a value anywhere in a JSON file replaced by generated JSON, a file
deleted), and for each copy:

* opening it and loading every frame's image, ground-truth depth, pose and disparity
  either works or raises a :class:`~vio_core.errors.VioDepthError` (one clear line in the
  CLI) -- never another exception (a traceback);
* it finishes within :data:`HANG_SECONDS` (never a hang);
* no input file changed (bytes compared before and after).

The examples are derandomised (the same 1 000 per loader on every run, so CI is
reproducible); ``VIO_DEPTH_HYPOTHESIS_RANDOM=1`` draws new ones,
``VIO_DEPTH_HYPOTHESIS_EXAMPLES=N`` changes the count.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vio_core.errors import VioDepthError
from vio_depth.disparity import DisparitySettings, create_disparity_source
from vio_depth.io import open_sequence

EXAMPLES = int(os.environ.get("VIO_DEPTH_HYPOTHESIS_EXAMPLES", "1000"))
HANG_SECONDS = 30
HERE = Path(__file__).resolve().parent
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, database=None, print_blob=True,
                    derandomize=not os.environ.get("VIO_DEPTH_HYPOTHESIS_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _test_module(name: str):
    spec = importlib.util.spec_from_file_location(f"_loader_builders_{name}", HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------- valid templates
def _read_tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _build(kind: str, base: Path) -> tuple[dict[str, bytes], str]:
    """(files of a valid sequence, relative path of the folder to open)."""
    if kind == "native":
        _test_module("test_native")._write(base / "seq")
        return _read_tree(base / "seq"), "."
    if kind == "kitti":
        drive, _, _ = _test_module("test_kitti").write_drive(base / "k", n=3, bins=False)
        depth_dir = drive / "proj_depth" / "velodyne" / "image_02"
        depth_dir.mkdir(parents=True)
        for i in range(2):
            d = np.zeros((30, 80), np.float32)
            d[10:20, 20:60] = 10.0
            np.savez_compressed(depth_dir / f"{i:010d}.npz", velodyne_depth=d)
        # the third frame's depth comes from a (small) raw scan instead: a wall 10 m ahead
        yy, zz = np.meshgrid(np.linspace(-5, 5, 10), np.linspace(-1, 1, 5))
        pts = np.stack([np.full(yy.size, 10.0), yy.ravel(), zz.ravel(), np.ones(yy.size)], 1).astype(np.float32)
        (drive / "velodyne_points" / "data").mkdir(parents=True, exist_ok=True)
        pts.tofile(drive / "velodyne_points" / "data" / f"{2:010d}.bin")
        return _read_tree(base / "k"), str(drive.relative_to(base / "k"))
    if kind == "7scenes":
        _test_module("test_sevenscenes").write_7scenes(base / "s", n=2)
        return _read_tree(base / "s"), "."
    if kind == "asl":
        pytest.importorskip("skimage")  # the generator's textures
        from vio_depth.simulate.asl import generate_asl_sample

        generate_asl_sample(base / "a" / "room", n_frames=3, scale=0.25)
        return _read_tree(base / "a"), "room"
    if kind == "tum":
        _test_module("test_tum").write_tum(base / "t" / "rgbd_dataset_freiburg3_x", n=3)  # the name sets the camera
        return _read_tree(base / "t"), "rgbd_dataset_freiburg3_x"
    raise ValueError(kind)


_TEMPLATES: dict[str, tuple[dict[str, bytes], str]] = {}


def template(kind: str) -> tuple[dict[str, bytes], str]:
    if kind not in _TEMPLATES:
        with tempfile.TemporaryDirectory() as tmp:
            _TEMPLATES[kind] = _build(kind, Path(tmp))
    return _TEMPLATES[kind]


# --------------------------------------------------------------------------- mutations
_TOKENS = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e-320", "0", "-0", "1" * 40, "0x10",
                     "1_0", "", "#", "\x00", "é", "∞", "images/x.png", "../x.png", "/etc/passwd", "rgb/a.png",
                     "data", "R:", "P_rect_02:", "T:", "2011-09-26 13:17:00.000000000", "{", "}", "[", "]",
                     '"format"', '"vio-depth-sequence"', "null", "true", "-1", "1e9", "4294967296"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**12, 10**12).map(str),
    st.text(max_size=12),
)
_LINE = st.lists(_TOKENS, max_size=10).map(" ".join)
_JSON = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=True, allow_infinity=True) | st.integers(-2**70, 2**70)
    | st.text(max_size=10) | st.sampled_from(["files", "simulated", "../x", "/abs", "vio-depth-sequence"]),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=10)
_MUTATION = st.one_of(
    st.tuples(st.just("json"), st.tuples(st.integers(0, 10**6), _JSON)),
    st.tuples(st.just("replace"), st.binary(max_size=300)),
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0)),
    st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), min_size=1,
                                        max_size=8)),
    st.tuples(st.just("line"), st.tuples(st.integers(0, 10**6), _LINE)),
    st.tuples(st.just("insert"), st.tuples(st.integers(0, 10**6), _LINE)),
    st.tuples(st.just("duplicate"), st.integers(0, 10**6)),
    st.tuples(st.just("delete"), st.none()),
)
MUTATIONS = st.lists(st.tuples(st.integers(0, 10**6), _MUTATION), min_size=1, max_size=3)


def mutate(files: dict[str, bytes], mutations) -> dict[str, bytes]:
    """A copy of ``files`` with the ``mutations`` applied (file chosen by index modulo count)."""
    files = dict(files)
    for which, (kind, payload) in mutations:
        if not files:
            break
        name = sorted(files)[which % len(files)]
        data = files[name]
        if kind == "delete":
            del files[name]
        elif kind == "replace":
            files[name] = payload
        elif kind == "json":
            files[name] = _mutate_json(data, *payload)
        elif kind == "truncate":
            files[name] = data[: int(payload * len(data))]
        elif kind == "flip":
            b = bytearray(data)
            for pos, value in payload:
                if b:
                    b[min(int(pos * len(b)), len(b) - 1)] = value
            files[name] = bytes(b)
        else:
            lines = data.split(b"\n")
            if kind == "duplicate":
                i = payload % len(lines)
                lines.insert(i, lines[i])
            else:
                i, text = payload
                i %= len(lines) + (kind == "insert")
                encoded = text.encode("utf-8", "surrogateescape")
                if kind == "line" and i < len(lines):
                    lines[i] = encoded
                else:
                    lines.insert(i, encoded)
            files[name] = b"\n".join(lines)
    return files


def _mutate_json(data: bytes, which: int, value) -> bytes:
    """Replace the ``which``-th value (any depth, modulo their count) of a JSON document by
    ``value``; other files get ``value`` as their whole content."""
    try:
        doc = json.loads(data)
    except ValueError:
        return json.dumps(value).encode()
    slots = []

    def walk(node):
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for k, v in items:
            slots.append((node, k))
            walk(v)

    walk(doc)
    if not slots:
        return json.dumps(value).encode()
    node, k = slots[which % len(slots)]
    node[k] = value
    return json.dumps(doc).encode()


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang(f"a loader ran for more than {HANG_SECONDS} s")


def exercise(root: Path) -> None:
    """Open the sequence and load everything of up to 4 frames; VioDepthError is the only
    acceptable failure."""
    try:
        seq = open_sequence(root)
        disparity = create_disparity_source(DisparitySettings(), seq) if seq.disparity is not None else None
        for i in range(min(len(seq), 4)):
            frame = seq[i]
            image = frame.image()
            assert image.shape == (seq.camera.height, seq.camera.width, 3) and image.dtype == np.uint8
            depth = frame.gt_depth()
            if depth is not None:
                assert depth.shape == image.shape[:2]
            if frame.T_w_c is not None:
                assert np.all(np.isfinite(frame.T_w_c))
            if disparity is not None:
                d = disparity(frame)
                assert d is None or d.shape == image.shape[:2]
        if seq.imu is not None:
            assert np.all(np.isfinite(seq.imu.gyro)) and np.all(np.isfinite(seq.imu.accel))
    except VioDepthError:
        pass


_ROOTS: dict[str, Path] = {}


def check_loader(kind: str, mutations, base: Path) -> None:
    """Damage the files of ``kind``'s folder (one folder per loader, restored after each
    example: creating and removing folders costs more than the loaders), exercise it,
    check that nothing changed."""
    files, open_at = template(kind)
    root = _ROOTS.get(kind)
    if root is None:
        root = _ROOTS[kind] = base / kind
        for name, data in files.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data)
    damaged = mutate(files, mutations)
    touched = [name for name in files if damaged.get(name) != files[name]]
    try:
        for name in touched:
            if name in damaged:
                (root / name).write_bytes(damaged[name])
            else:
                (root / name).unlink()
        before = _read_tree(root)
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(HANG_SECONDS)
        try:
            exercise(root / open_at)
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
        assert _read_tree(root) == before, "the loader changed its input"
    finally:
        for name in touched:
            (root / name).write_bytes(files[name])


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return tmp_path_factory.mktemp("loaders")


@pytest.mark.parametrize("kind", ["native", "kitti", "7scenes", "tum", "asl"])
def test_templates_are_valid_sequences(kind, tmp_path):
    files, open_at = template(kind)
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    seq = open_sequence(tmp_path / open_at)
    assert len(seq) >= 2 and seq[1].image().ndim == 3


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["native", "kitti", "7scenes", "tum", "asl"])
@SETTINGS
@given(mutations=MUTATIONS)
def test_loader_never_tracebacks_hangs_or_writes(base, kind, mutations):
    check_loader(kind, mutations, base)
