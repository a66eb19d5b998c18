"""Shared fixtures: small copies of the bundled street sample that tests may modify."""

import shutil
from pathlib import Path

import pytest

STREET = Path(__file__).resolve().parents[2] / "sample_sequences" / "street"


def copy_street(dst: Path, n: int) -> Path:
    """A native sequence at ``dst`` with the first ``n`` frames of the street sample (SIMULATED disparity)."""
    dst.mkdir(parents=True)
    for name in ("sequence.json", "poses.txt", "imu.txt"):
        shutil.copy(STREET / name, dst / name)
    lines = [ln for ln in (STREET / "frames.txt").read_text().splitlines() if ln and not ln.startswith("#")][:n]
    (dst / "frames.txt").write_text("\n".join(lines) + "\n")
    (dst / "images").mkdir()
    (dst / "depth").mkdir()
    for ln in lines:
        stem = Path(ln.split()[1]).stem
        shutil.copy(STREET / "images" / f"{stem}.jpg", dst / "images" / f"{stem}.jpg")
        shutil.copy(STREET / "depth" / f"{stem}.png", dst / "depth" / f"{stem}.png")
    return dst


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
