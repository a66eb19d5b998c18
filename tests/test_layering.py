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


#: packages of one layer that stay independent of each other (each stage's settings live next to its
#: code: the odometry's in vio_depth.vio, so the pose stage needs nothing of the landmark window)
INDEPENDENT = [("vio_depth.poses", "vio_depth.landmarks")]


@pytest.mark.parametrize("package, other", INDEPENDENT)
def test_independent_packages_do_not_import_each_other(package, other):
    known = _modules()
    bad = [f"{m} imports {n}" for m, p in known.items() for n in _imports(m, p, known)
           for a, b in ((package, other), (other, package))
           if (m == a or m.startswith(a + ".")) and (n == b or n.startswith(b + "."))]
    assert not bad, bad


# --------------------------------------------------------------------------- registries filled by imports
#: calls that make an empty or literal container
CONTAINER_CALLS = {"dict", "list", "set", "defaultdict", "OrderedDict", "deque"}
#: methods that put something into a container
FILLING_METHODS = {"append", "appendleft", "extend", "insert", "update", "setdefault", "add", "__setitem__"}


def _is_container(value) -> bool:
    if isinstance(value, (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)):
        return True
    if isinstance(value, ast.Call):
        f = value.func
        return (f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None) in CONTAINER_CALLS
    return False


def _dotted(node) -> str | None:
    """``a.b.c`` of a Name / Attribute chain, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return ".".join([node.id] + parts[::-1])


def _import_time_nodes(body):
    """Every node of a module body that runs at import: not the bodies of functions (their
    decorators and default values do run), but class bodies and module-level blocks."""
    stack = list(body)
    while stack:
        node = stack.pop()
        yield node
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack += getattr(node, "decorator_list", []) + node.args.defaults + [d for d in node.args.kw_defaults if d]
            continue
        stack += list(ast.iter_child_nodes(node))


class _Module:
    def __init__(self, name: str, source: str, is_package: bool):
        self.name = name
        self.tree = ast.parse(source)
        self.is_package = is_package
        #: module-level names bound to a container
        self.containers = {t.id for node in self.tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
                           and node.value is not None and _is_container(node.value)
                           for t in (node.targets if isinstance(node, ast.Assign) else [node.target])
                           if isinstance(t, ast.Name)}
        self.functions = {n.name: n for n in self.tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        #: local alias -> (module, name), name None for a module
        self.aliases: dict[str, tuple[str, str | None]] = {}
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    self.aliases[a.asname or a.name.split(".")[0]] = (a.name if a.asname else a.name.split(".")[0], None)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = name.split(".") if is_package else name.split(".")[:-1]
                    parts = parts[: len(parts) - (node.level - 1)]
                    base = ".".join(parts + ([node.module] if node.module else []))
                for a in node.names:
                    self.aliases[a.asname or a.name] = (base, a.name)


class RegistryCheck:
    """Finds module-level registries filled by imports in a set of modules (``{name: (source, is_package)}``)."""

    def __init__(self, sources: dict[str, tuple[str, bool]]):
        self.modules = {name: _Module(name, src, pkg) for name, (src, pkg) in sources.items()}

    def _origin(self, module: str, name: str, depth: int = 0) -> tuple[str, str] | None:
        """Where ``name`` of ``module`` is defined (following imports and re-exports)."""
        m = self.modules.get(module)
        if m is None or depth > 10:
            return None
        if name in m.functions or name in m.containers:
            return module, name
        if name in m.aliases:
            target, attr = m.aliases[name]
            if attr is None:
                return None
            if f"{target}.{attr}" in self.modules:  # `from pkg import module`
                return None
            return self._origin(target, attr, depth + 1)
        return None

    def _resolve(self, module: _Module, expr) -> tuple[str, str] | None:
        """The (module, name) an expression (``f``, ``mod.f``, ``pkg.mod.f``) refers to, if a project name."""
        dotted = _dotted(expr)
        if dotted is None:
            return None
        head, *rest = dotted.split(".")
        if not rest:
            return self._origin(module.name, head)
        if head not in module.aliases:
            return None
        target, attr = module.aliases[head]
        prefix = target if attr is None else f"{target}.{attr}"
        *mods, last = rest
        return self._origin(".".join([prefix] + mods), last)

    def _filled_containers(self, module: _Module, fn) -> set[tuple[str, str]]:
        """Module-level containers (of any module) that the body of ``fn`` puts things into."""
        local = {t.id for node in ast.walk(fn) if isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign))
                 for t in (node.targets if isinstance(node, ast.Assign) else [node.target]) if isinstance(t, ast.Name)}
        local -= {n for node in ast.walk(fn) if isinstance(node, ast.Global) for n in node.names}
        local |= {a.arg for a in fn.args.args + fn.args.kwonlyargs + fn.args.posonlyargs}
        out = set()
        for node in ast.walk(fn):
            self._collect(module, node, out, skip=local)
        return out

    def _collect(self, module: _Module, node, out: set, skip=frozenset()):
        targets = []
        if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = [t.value for t in (node.targets if isinstance(node, ast.Assign) else [node.target])
                       if isinstance(t, ast.Subscript)]
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in FILLING_METHODS:
            targets = [node.func.value]
        for t in targets:
            if isinstance(t, ast.Name) and t.id in skip:
                continue
            origin = self._resolve(module, t)
            if origin is not None and origin[1] in self.modules[origin[0]].containers:
                out.add(origin)

    def violations(self) -> list[str]:
        filling = {(m.name, name): self._filled_containers(m, fn)
                   for m in self.modules.values() for name, fn in m.functions.items()}
        bad = []
        for m in self.modules.values():
            for fn in (n for n in ast.walk(m.tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))):
                if fn.name.lower().startswith("register") and self._filled_containers(m, fn):
                    bad.append(f"{m.name}:{fn.lineno} {fn.name}() fills a module-level container (a registry)")
            for node in _import_time_nodes(m.tree.body):
                direct: set[tuple[str, str]] = set()
                self._collect(m, node, direct)
                for owner, container in sorted(direct):
                    if owner != m.name:
                        bad.append(f"{m.name}:{node.lineno} fills {owner}.{container} at import time")
                called = [node.func] if isinstance(node, ast.Call) else []
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    called += [d for d in node.decorator_list if not isinstance(d, ast.Call)]  # @register
                for c in called:
                    callee = self._resolve(m, c)
                    for owner, container in sorted(filling.get(callee, ())):
                        if owner != m.name:
                            bad.append(f"{m.name}:{c.lineno} calls {callee[0]}.{callee[1]}() at import time, "
                                       f"which fills {owner}.{container}")
        return bad


def test_no_module_level_registry_is_filled_by_imports():
    """Choices are explicit tables and calls: importing a module never fills another module's
    container, and no ``register_*`` function fills a module-level one."""
    sources = {name: (path.read_text(encoding="utf-8"), path.name == "__init__.py") for name, path in _modules().items()}
    bad = RegistryCheck(sources).violations()
    assert not bad, "\n".join(bad)


def test_the_registry_check_finds_registries_filled_by_imports():
    """The check refuses what the sequence loaders and the vio pose source did before."""
    base = ("_FORMATS = {}\n\n\ndef register_format(fmt):\n    _FORMATS[fmt.name] = fmt\n    return fmt\n\n\n"
            "def open_sequence(path):\n    return [f for f in _FORMATS.values() if f.detect(path)]\n")
    registries = {
        "pkg": ("from .base import register_format\n", True),
        "pkg.base": (base, False),
        "pkg.kitti": ("from .base import register_format\n\nFORMAT = register_format(object())\n", False),
        "pkg.tum": ("from . import base\n\n\nclass Tum:\n    base.register_format(object())\n", False),
        "pkg.asl": ("from pkg import register_format\n\n\n@register_format\nclass Asl:\n    pass\n", False),
        "pkg.vio": ("from . import base\n\nbase._FORMATS['vio'] = object()\nbase._FORMATS.setdefault('x', 1)\n", False),
    }
    bad = "\n".join(RegistryCheck(registries).violations())
    assert "pkg.base:4 register_format() fills a module-level container" in bad
    for line in ("pkg.kitti:3 calls pkg.base.register_format()", "pkg.tum:5 calls pkg.base.register_format()",
                 "pkg.asl:4 calls pkg.base.register_format()", "pkg.vio:3 fills pkg.base._FORMATS",
                 "pkg.vio:4 fills pkg.base._FORMATS"):
        assert line in bad, bad
    explicit = {  # the same, as an explicit table built by explicit imports, and a cache filled at run time
        "pkg": ("from .formats import FORMATS\n", True),
        "pkg.kitti": ("FORMAT = object()\n", False),
        "pkg.formats": ("from . import kitti\n\nFORMATS = (kitti.FORMAT,)\nBY_NAME = {f: f for f in FORMATS}\n", False),
        "pkg.cache": ("_CACHE = {}\n\n\ndef load(key):\n    _CACHE[key] = key\n    return _CACHE[key]\n", False),
        "pkg.user": ("from .cache import load\n\n\ndef main():\n    load('a')\n", False),
    }
    assert RegistryCheck(explicit).violations() == []
