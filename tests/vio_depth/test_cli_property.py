"""Issue 12, "What to build" 6: property-based tests of the CLI's argument handling.

Generated command lines (every settings flag with generated values: numbers such as NaN,
inf, negatives, 1e400, garbage text, odd paths, generated TOML config files) must end in
one of the documented ways, never a traceback:

* ``config --dump`` (:data:`CONFIG_EXAMPLES` = 1 000 command lines): exit 0 with TOML that
  reads back to the same settings; exit 1 with exactly one line ``vio-depth: error: ...``;
  or argparse's usage error (exit 2).
* ``run`` on a tiny native sequence (:data:`RUN_EXAMPLES` = 150 command lines; each one a
  real run): exit 0 or 3 with a complete ``--out`` and no staging folder left; exit 1 with
  one line and ``--out`` untouched; or exit 2. The input sequence never changes.

Derandomised like the loader tests (``VIO_DEPTH_HYPOTHESIS_RANDOM=1`` for new examples).
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vio_depth.cli import main
from vio_depth.run import load_config, staging_path

CONFIG_EXAMPLES = int(os.environ.get("VIO_DEPTH_HYPOTHESIS_EXAMPLES", "1000"))
RUN_EXAMPLES = max(1, CONFIG_EXAMPLES * 3 // 20)
HERE = Path(__file__).resolve().parent


def _settings(n: int):
    return settings(max_examples=n, deadline=None, database=None, print_blob=True,
                    derandomize=not os.environ.get("VIO_DEPTH_HYPOTHESIS_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


NUMBER = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "-1", "0", "-0", "0.5", "3", "1e-9", "0x1", "", " 2",
                     "1_000", "10", "2"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.text(max_size=8),
)
TEXT = st.one_of(st.text(max_size=12), st.sampled_from(["", "-", "--", "..", "/", os.fsdecode(b"\xff\xfe"),
                                                        "a" * 300, "x:y:z"]))
TOML = st.lists(st.one_of(
    st.sampled_from(["[pairing]", "[matcher]", "[run]", "[rescaler]", "[rescaler.ransac]", "[disparity]",
                     "[points]", "[triangulation]", "[poses]", "[run.export]", "[nope]", "preset = 'indoor'",
                     "preset = 'mars'", "min_translation_m = nan", "min_translation_m = -1", "max_frames = 2",
                     "max_frames = -2", "max_eval_depth = 0.0", "seed = -1", "ratio = 2.0", "backfill = 3",
                     "min_depth_fraction = 2", "max_fallback_error = inf", "source = 'model'", "x = [1, 2]",
                     "min_valid_fraction = 0.5", "temporal = 'off'", "= 1", "[[run]]", "'"]),
    st.text(max_size=20)), max_size=6).map("\n".join)

# flag -> value strategy (None: a switch without a value)
FLAGS: dict[str, st.SearchStrategy | None] = {
    "--matcher": st.sampled_from(["sift", "SIFT", "surf", "disk+lightglue", "xfeat+lighterglue", ""]),
    "--device": st.sampled_from(["cpu", "cuda", "gpu"]),
    "--poses": st.sampled_from(["gt", "imu", "gps", "GT", ""]),
    "--pairing": st.sampled_from(["kitti", "ddad", "indoor", "mars", "Indoor"]),
    "--min-rotation": NUMBER,
    "--min-translation": NUMBER,
    "--rescaler": st.sampled_from(["streaming", "per_frame", "paper", "fast"]),
    "--no-temporal": None,
    "--guided-matching": None,
    "--points": st.one_of(st.sampled_from(["sfm", "vio", "vio:3", "lidar:16", "random:100", "lidar:-1", "lidar:x",
                                           "radar:3", "lidar:", "random:1e9"]), TEXT),
    "--seed": NUMBER,
    "--disparity": st.one_of(st.sampled_from(["sequence", "files", "simulated", "model", "x/y.npy"]), TEXT),
    "--disparity-dir": st.sampled_from(["@missing", "@file", "@empty", "@seq"]),
    "--model": st.sampled_from(["@missing", "@file", "model.onnx"]),
    "--model-variant": st.one_of(st.sampled_from(["vits", "v2-vitl", "huge"]), TEXT),
    "--model-input-size": NUMBER,
    "--max-frames": NUMBER,
    "--no-backfill": None,
    "--uncertainty": None,
    "--max-depth": NUMBER,
    "--save-npy": None,
    "--save-preview": None,
    "--preview-range": st.one_of(st.tuples(NUMBER, NUMBER).map(":".join), TEXT),
    "--preview-colormap": st.one_of(st.sampled_from(["turbo", "viridis", "jet"]), TEXT),
    "--save-ply": st.one_of(st.sampled_from(["sparse", "dense", "dense:4", "dense:0", "sparse,dense:2", "mesh"]),
                            TEXT),
    "--ply-frames": st.one_of(st.sampled_from(["0,1", "0:5:2", "0:5:0", "-1", "a"]), TEXT),
    "--config": TOML,
    "--format": st.sampled_from(["native", "kitti_raw", "7scenes", "tum_rgbd", "asl"]),
    "--overwrite": None,
    "--resume": None,
}
CONFIG_FLAGS = [f for f in FLAGS if f not in ("--format", "--overwrite", "--resume")]
RUN_FLAGS = [f for f in FLAGS if f not in ("--matcher", "--model", "--report")]  # no network weights, no torch

RUN_MATCHERS = st.sampled_from(["sift", "SIFT", "surf", ""])


def _argv(draw_pairs, root: Path, seq: Path) -> list[str]:
    argv = []
    for flag, value in draw_pairs:
        argv.append(flag)
        if value is None:
            continue
        if flag == "--config":
            path = root / f"c{len(argv)}.toml"
            path.write_text(value, encoding="utf-8", errors="surrogateescape")
            value = str(path)
        elif flag in ("--disparity-dir", "--model") and value.startswith("@"):
            value = {"@missing": str(root / "missing"), "@file": str(root / "file.txt"),
                     "@empty": str(root / "empty"), "@seq": str(seq)}[value]
        argv.append(value)
    return argv


def _pairs(flags: list[str], override: dict | None = None):
    override = override or {}

    def one(flag):
        strategy = override.get(flag, FLAGS[flag])
        return st.tuples(st.just(flag), st.none() if strategy is None else strategy)

    return st.lists(st.sampled_from(flags).flatmap(one), max_size=6)


def _call(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:  # argparse: usage error (2) or --help (0)
            rc = exc.code if isinstance(exc.code, int) else 2
            assert rc in (0, 2), rc
            return -rc if rc else 0, out.getvalue(), err.getvalue()
    return rc, out.getvalue(), err.getvalue()


def _one_error_line(err: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("vio-depth: error: "), err
    assert "Traceback" not in err


class Workspace(tuple):
    """(root, sequence folder, its files' bytes), with a short repr for hypothesis' reports."""

    def __repr__(self):
        return f"Workspace({self[0]})"


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    (root / "file.txt").write_text("not a folder")
    (root / "empty").mkdir()
    spec = importlib.util.spec_from_file_location("_cli_native_builder", HERE / "io" / "test_native.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    seq = root / "seq"
    module._write(seq)
    digest = {str(p.relative_to(seq)): p.read_bytes() for p in sorted(seq.rglob("*")) if p.is_file()}
    return Workspace((root, seq, digest))


@pytest.mark.slow
@_settings(CONFIG_EXAMPLES)
@given(pairs=_pairs(CONFIG_FLAGS))
def test_config_dump_never_tracebacks(workspace, pairs):
    root, seq, _ = workspace
    argv = ["config", "--dump", *_argv(pairs, root, seq)]
    rc, out, err = _call(argv)
    if rc == 0:
        dumped = root / "dumped.toml"
        dumped.write_text(out)
        assert load_config(dumped)  # what was printed reads back
    elif rc == 1:
        _one_error_line(err)
    else:
        assert rc == -2 and "error:" in err.splitlines()[-1]


@pytest.mark.slow
@_settings(RUN_EXAMPLES)
@given(pairs=_pairs(RUN_FLAGS, {"--max-frames": st.sampled_from(["1", "2", "3", "0", "-1", "x", "nan"])}),
       matcher=st.none() | RUN_MATCHERS)
def test_run_never_tracebacks_and_never_touches_its_input(workspace, pairs, matcher):
    root, seq, digest = workspace
    out = root / "out"
    for p in (out, staging_path(out)):
        shutil.rmtree(p, ignore_errors=True)
    argv = ["-q", "run", str(seq), "--out", str(out), "--no-progress", *_argv(pairs, root, seq)]
    if matcher is not None:
        argv += ["--matcher", matcher]
    rc, _, err = _call(argv)
    if rc in (0, 3):
        assert (out / "frames.jsonl").is_file() and not staging_path(out).exists()
        if rc == 3:
            assert err.startswith("vio-depth: ") and len(err.strip().splitlines()) == 1, err
    elif rc == 1:
        _one_error_line(err)
        assert not out.exists()
        if staging_path(out).exists():
            assert "--resume continues it" in err
    else:
        assert rc == -2, (rc, err)
    now = {str(p.relative_to(seq)): p.read_bytes() for p in sorted(seq.rglob("*")) if p.is_file()}
    assert now == digest, "the run changed its input sequence"
