"""The guard that proves vio-depth never changes a file it did not create (issue 23).

For the safety tests (``tests/robustness/``, ``tests/vio_depth/test_cli_safety.py``,
``tests/vio_depth/run/test_output_folder.py``) every ``vio-depth`` command run in-process is
wrapped: the test's folder (``tmp_path``: its input sequences and the "user's" folders) is
walked before and after the command and every file hashed. A file that existed before must
be there afterwards with the same bytes, unless it lay in a folder that carried one of
vio-depth's markers before the command (a run, evaluation or report folder vio-depth wrote,
or a staging folder of its own: those it may replace). New files are allowed (outputs).

The bundled samples (``sample_sequences/``, read by many tests) are hashed once before the
whole session and compared at its end.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
GUARDED = ("tests/robustness/", "tests/vio_depth/test_cli_safety.py", "tests/vio_depth/run/test_output_folder.py")
MARKER_KINDS = ("run", "eval", "report")


def snapshot(*roots: Path) -> tuple[dict[str, str], list[Path]]:
    """``({path: hash}, [folders carrying a vio-depth marker])`` of every file under ``roots``
    (links are recorded by their target, never followed)."""
    from vio_depth.io.marker import read_marker

    files: dict[str, str] = {}
    owned: list[Path] = []
    for root in roots:
        for dirpath, _, filenames in os.walk(root):
            d = Path(dirpath)
            if any(read_marker(d, kind) is not None for kind in MARKER_KINDS):
                owned.append(d)
            for name in filenames:
                p = d / name
                try:
                    if p.is_symlink():
                        files[str(p)] = "link:" + os.readlink(p)
                    else:
                        files[str(p)] = hashlib.sha1(p.read_bytes()).hexdigest()
                except OSError:
                    files[str(p)] = "unreadable"
    return files, owned


Snapshot = tuple[dict[str, str], list[Path]]


def changed_user_files(before: Snapshot, after: Snapshot) -> list[str]:
    """Files of ``before`` outside its vio-depth folders that ``after`` lacks or holds changed."""
    files, owned = before
    now = after[0]
    out = []
    for path, h in files.items():
        if any(Path(path) == o or o in Path(path).parents for o in owned):
            continue
        if now.get(path) != h:
            out.append(f"{path}: {'deleted' if path not in now else 'modified'}")
    return out


@pytest.fixture(autouse=True)
def _guard_user_files(request, monkeypatch):
    """Wrap ``vio_depth.cli._main`` in the safety tests (see the module docstring)."""
    nodeid = request.node.nodeid.replace("\\", "/")
    if not any(g in nodeid for g in GUARDED):
        yield
        return
    import vio_depth.cli as cli

    tmp = request.getfixturevalue("tmp_path")
    original = cli._main

    def guarded(args):
        before = snapshot(tmp)
        try:
            return original(args)
        finally:
            damage = changed_user_files(before, snapshot(tmp))
            assert not damage, f"vio-depth {args.command} changed files it did not create: {damage[:5]}"

    monkeypatch.setattr(cli, "_main", guarded)
    yield


@pytest.fixture(scope="session", autouse=True)
def _samples_unchanged():
    """The bundled samples are inputs of many tests: byte-identical at the end of the session."""
    samples = ROOT / "sample_sequences"
    before = snapshot(samples)[0] if samples.is_dir() else {}
    yield
    if before:
        after = snapshot(samples)[0]
        damage = [p for p, h in before.items() if after.get(p) != h]
        assert not damage, f"the bundled samples changed during the tests: {damage[:5]}"


# ---------------------------------------------------------------- small copies of the street sample
STREET = ROOT / "sample_sequences" / "street"


def copy_native_prefix(src: Path, dst: Path, n: int, poses: str = "keep") -> Path:
    """A native sequence at ``dst`` with the first ``n`` frames of the native sequence ``src``
    (a bundled sample: SIMULATED disparity). ``poses``: ``keep`` (as they are), ``scramble``
    (the poses.txt rows shuffled among the timestamps, seed 0) or ``drop`` (no poses.txt, no
    "poses" key in sequence.json)."""
    if poses not in ("keep", "scramble", "drop"):
        raise ValueError(f"poses: keep, scramble or drop, got {poses!r}")
    dst.mkdir(parents=True)
    lines = [ln for ln in (src / "frames.txt").read_text().splitlines() if ln and not ln.startswith("#")][:n]
    (dst / "frames.txt").write_text("\n".join(lines) + "\n")
    shutil.copy(src / "imu.txt", dst / "imu.txt")
    (dst / "images").mkdir()
    (dst / "depth").mkdir()
    for ln in lines:
        stem = Path(ln.split()[1]).stem
        shutil.copy(src / "images" / f"{stem}.jpg", dst / "images" / f"{stem}.jpg")
        shutil.copy(src / "depth" / f"{stem}.png", dst / "depth" / f"{stem}.png")
    if poses == "keep":
        for name in ("sequence.json", "poses.txt"):
            shutil.copy(src / name, dst / name)
        return dst
    meta = json.loads((src / "sequence.json").read_text())
    if poses == "drop":
        del meta["poses"]
    else:
        rows = [ln.split() for ln in (src / "poses.txt").read_text().splitlines() if ln and not ln.startswith("#")]
        order = np.random.default_rng(0).permutation(len(rows))
        rows = [[r[0]] + rows[j][1:] for r, j in zip(rows, order)]
        (dst / "poses.txt").write_text("\n".join(" ".join(r) for r in rows) + "\n")
    (dst / "sequence.json").write_text(json.dumps(meta))
    return dst


def copy_street(dst: Path, n: int) -> Path:
    """A native sequence at ``dst`` with the first ``n`` frames of the street sample (SIMULATED disparity)."""
    return copy_native_prefix(STREET, dst, n)


@pytest.fixture
def native_prefix():
    """:func:`copy_native_prefix`: ``native_prefix(src, dst, n, poses="keep"|"scramble"|"drop")``."""
    return copy_native_prefix


#: ``--matcher sift`` for a run over a few street frames: they are 0.4 m apart, so only SIFT's
#: weak pairs (below the pairing's 1.5 m) give them depth; klt, the default matcher with the
#: sequence's poses, pairs none (``TRACKER_DEFAULTS``) and such a run ends in exit 3. Tests of
#: folders, files and statuses on short clips name sift to keep testing what they test.
SHORT_CLIP = ("--matcher", "sift")


@pytest.fixture
def short_clip() -> tuple[str, ...]:
    """:data:`SHORT_CLIP`: the flags a CLI run over a few street frames adds to get depth."""
    return SHORT_CLIP


@pytest.fixture
def mini_street(tmp_path):
    """Factory: ``mini_street(n=10, name="seq")`` copies the first n frames of the street sample."""
    if not (STREET / "sequence.json").exists():
        pytest.skip("bundled street sample missing")

    def make(n: int = 10, name: str = "seq") -> Path:
        return copy_street(tmp_path / name, n)

    return make


def tree_digest(root: Path) -> dict:
    """``{relative path: bytes}`` of every file under ``root`` (to prove inputs unchanged)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def digest():
    return tree_digest
