"""The package layering: no import cycle, lower layers never import upper ones, and the leaf
layers (vio_core, matchers, triangulation) import without vio_depth."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("vio_core", "matchers", "triangulation", "vio_depth")

# Rank of each layer: a module may import modules of its own or a lower rank only.
RANKS = {
    "vio_core": 0,
    "matchers": 1,
    "triangulation": 1,
    "vio_depth._version": 2,
    "vio_depth.frame": 2,
    "vio_depth.models": 2,
    "vio_depth.disparity": 3,
    "vio_depth.io": 4,
    "vio_depth.landmarks": 5,
    "vio_depth.poses": 5,
    "vio_depth.keyframes": 5,
    "vio_depth.rescale": 5,
    "vio_depth.evaluation": 6,
    "vio_depth.vio": 6,
    "vio_depth.export": 6,
    "vio_depth.report": 7,
    "vio_depth.pipeline": 7,
    "vio_depth.baselines": 7,  # re-implemented published methods, beside the pipeline
    "vio_depth.run": 8,
    "vio_depth.simulate": 9,
    "vio_depth.experiments": 9,  # vio-depth eval: runs (8) and baselines (7) over many sequences
    "vio_depth.cli": 9,
    "vio_depth.cli_robot": 9,  # the command line of bags, calibration, ROS outputs and Rerun
    "vio_depth.viz": 8,  # live views (Rerun), beside the runs
    "vio_depth": 10,  # the package __init__: the public API
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            out[_module_name(path)] = path
    return out


def _imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """Project modules imported by ``name`` (explicit imports anywhere in the file)."""
    is_package = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        else:
            continue
        for t in targets:
            if t in known:
                found.add(t)
    found.discard(name)
    return found


def _rank(module: str) -> int:
    best = None
    for prefix, rank in RANKS.items():
        if module == prefix or module.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, rank)
    assert best is not None and (best[0] != "vio_depth" or module == "vio_depth"), \
        f"{module}: not in the layer table of tests/test_layering.py"
    return best[1]


def test_no_import_cycle_between_modules():
    known = _modules()
    graph = {m: _imports(m, p, known) for m, p in known.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                cycle = stack[stack.index(n):] + [n]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_lower_layers_never_import_upper_ones():
    known = _modules()
    bad = []
    for m, p in known.items():
        for n in _imports(m, p, known):
            if _rank(n) > _rank(m):
                bad.append(f"{m} (layer {_rank(m)}) imports {n} (layer {_rank(n)})")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package, blocked", [
    ("vio_core", ("vio_depth", "matchers", "triangulation")),
    ("matchers", ("vio_depth", "triangulation")),
    ("triangulation", ("vio_depth", "matchers")),
])
def test_leaf_package_imports_alone(package, blocked):
    """Each leaf imports in a fresh interpreter where the upper packages cannot be imported."""
    code = (
        "import sys\n"
        f"for name in {blocked!r}:\n"
        "    sys.modules[name] = None  # `import name` now raises ImportError\n"
        f"import {package}\n"
        f"for name in {package}.__all__:\n"
        f"    getattr({package}, name)\n"
        "print('ok')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_every_public_name_is_exported_by_its_package():
    """Each package ``__init__`` lists names that exist (``from pkg import *`` works)."""
    code = (
        "import importlib\n"
        f"for pkg in {list(PACKAGES) + ['vio_depth.io', 'vio_depth.disparity', 'vio_depth.poses', 'vio_depth.rescale', 'vio_depth.evaluation', 'vio_depth.pipeline', 'vio_depth.run', 'vio_depth.baselines', 'vio_depth.experiments']!r}:\n"
        "    m = importlib.import_module(pkg)\n"
        "    missing = [n for n in m.__all__ if not hasattr(m, n)]\n"
        "    assert not missing, (pkg, missing)\n"
        "print('ok')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_no_module_is_over_500_lines():
    long = {m: n for m, p in _modules().items() if (n := len(p.read_text().splitlines())) > 500}
    assert not long, long


#: optional heavy dependencies: the only imports allowed inside a function (imported where selected)
LAZY_IMPORTS = {"torch", "torchvision", "kornia", "transformers", "onnxruntime", "onnx", "gtsam", "matplotlib", "ray",
                "rerun", "sklearn", "skimage", "plyfile", "evo", "safetensors", "PIL", "huggingface_hub"}


def test_imports_inside_functions_are_only_optional_heavy_dependencies():
    inside = []
    for name, path in _modules().items():
        for fn in ast.walk(ast.parse(path.read_text())):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    tops = [a.name.split(".")[0] for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    tops = ["." * node.level + (node.module or "")] if node.level else [node.module.split(".")[0]]
                else:
                    continue
                inside += [f"{name}:{node.lineno} imports {t}" for t in tops if t not in LAZY_IMPORTS]
    assert not sorted(set(inside)), sorted(set(inside))
