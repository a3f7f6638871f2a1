"""No import circles in ``src/opnet``, at two granularities.

- Modules: every ``.py`` file is a node, an ``import`` / ``from ... import`` statement an edge
  (relative imports resolved; ``from a import b`` goes to the module ``a.b`` when there is one,
  else to ``a``). Two graphs: the imports that run when a module is loaded (module scope,
  including ``if`` / ``try`` / ``with`` / class bodies, excluding function bodies and
  ``if TYPE_CHECKING:`` blocks), where a circle is a real import-time circle; and every import,
  function-level ones included, where a circle is two modules that need each other (the old
  ``synthesis/physics.py``, whose ``make_simulator`` imported the engines that import it). Both must
  be free of circles, inside a package as between packages.
- Packages: each package (``cli``, ``data``, ``synthesis``, ...) and each top-level module
  (``inference``, ``system``, ...) is one node; every import counts. A circle means a low layer
  reaches up into a high one (the inference engine into the command line, the generator into the
  console).

Not counted: the parent packages an import runs first (``import a.b.c`` runs ``a/__init__`` and
``a/b/__init__``; counting them would make every package whose ``__init__`` imports its own
submodules a circle, which Python handles), and imports by name at run time
(``importlib.import_module``, :func:`opnet._lazy.lazy_exports`)."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict, deque
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

SRC = REPO_ROOT / "src"

#: node -> node it imports -> where (``path:line``, relative to the root) the imports making the edge are
Graph = dict[str, dict[str, set[str]]]


def _module_name(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")  # fmt: skip


def _imports(body: list[ast.stmt], deferred: bool) -> Iterator[ast.Import | ast.ImportFrom]:
    """The import statements of ``body`` that run when it runs; with ``deferred``, those in the
    functions it defines too."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if deferred:
                yield from (n for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            yield from _imports(node.orelse, deferred)
        else:  # if / for / while / with / try / match / class: their bodies run with the module
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.ExceptHandler, ast.match_case)):
                    yield from _imports(child.body, deferred)
            for name in ("body", "orelse", "finalbody"):
                block = getattr(node, name, None)
                if isinstance(block, list):
                    yield from _imports(block, deferred)


def module_graph(src: Path, top: str, *, deferred: bool = False) -> Graph:
    """The import graph between the modules of the package ``src/top`` (see the module docstring);
    ``deferred`` counts the imports inside functions too."""
    files = {_module_name(path, src): path for path in sorted((src / top).rglob("*.py"))}

    def resolve(name: str) -> str | None:  # the longest prefix that is a module of the tree
        parts = name.split(".")
        for k in range(len(parts), 0, -1):
            if ".".join(parts[:k]) in files:
                return ".".join(parts[:k])
        return None

    graph: Graph = defaultdict(lambda: defaultdict(set))
    for module, path in files.items():
        package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
        for node in _imports(ast.parse(path.read_text(), str(path)).body, deferred):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                origin = node.module or ""
                if node.level:  # relative: against this module's package
                    origin = ".".join(package[: len(package) - node.level + 1] + ([origin] if origin else []))
                names = [f"{origin}.{a.name}" for a in node.names]
            for name in names:
                there = resolve(name)
                if there is not None and there != module:
                    graph[module][there].add(f"{path.relative_to(src).as_posix()}:{node.lineno}")
    return graph


def package_graph(src: Path, top: str) -> Graph:
    """:func:`module_graph` with every import counted and each package / top-level module of
    ``top`` collapsed to one node (``top``'s own ``__init__`` left out)."""
    graph: Graph = defaultdict(lambda: defaultdict(set))
    for a, targets in module_graph(src, top, deferred=True).items():
        for b, where in targets.items():
            here, there = a.split(".")[1:2], b.split(".")[1:2]  # [] for top's own __init__
            if here and there and here != there:
                graph[here[0]][there[0]] |= where
    return graph


def circles(graph: Graph) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in list(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def cycle_through(graph: Graph, component: list[str]) -> list[str]:
    """A shortest circle through the first node of ``component``: ``[a, b, ..., a]``."""
    start, inside = component[0], set(component)
    before: dict[str, str] = {}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w in sorted(graph.get(v, {})):
            if w == start:
                back = [v]
                while back[-1] != start:
                    back.append(before[back[-1]])
                return [*reversed(back), start]
            if w in inside and w not in before:
                before[w] = v
                queue.append(w)
    raise AssertionError(f"{component} is no circle")  # a component of more than one node always is


def describe(graph: Graph, component: list[str]) -> str:
    """The circle through ``component``, each edge with the imports that make it."""
    cycle = cycle_through(graph, component)
    edges = [f"  {a} -> {b}  ({', '.join(sorted(graph[a][b]))})" for a, b in pairwise(cycle)]
    also = f" (all of {', '.join(component)} are on circles)" if len(component) > len(cycle) - 1 else ""
    return "import circle: " + " -> ".join(cycle) + also + "\n" + "\n".join(edges)


def import_circles(src: Path, top: str, *, deferred: bool = False) -> list[str]:
    """Every circle of :func:`module_graph`, described; empty when there is none."""
    graph = module_graph(src, top, deferred=deferred)
    return [describe(graph, c) for c in circles(graph)]


# ---- opnet -----------------------------------------------------------------------------------
def test_no_import_circle_between_the_modules_of_opnet() -> None:
    graph = module_graph(SRC, "opnet")
    assert len(graph) > 50 and "opnet.synthesis.physics.base" in graph["opnet.synthesis.physics"]  # the walk saw the modules
    assert not (found := import_circles(SRC, "opnet")), "\n".join(found)


def test_no_circle_between_the_modules_of_opnet_counting_function_level_imports() -> None:
    assert not (found := import_circles(SRC, "opnet", deferred=True)), "\n".join(found)


def test_no_circle_between_the_packages_of_opnet() -> None:
    graph = package_graph(SRC, "opnet")
    assert len(graph) > 10  # the walk saw the packages
    found = circles(graph)
    assert not found, "\n".join(describe(graph, c) for c in found)


LOW_LAYERS = ("opnet.inference", "opnet.estimator", "opnet.system", "opnet.data.scene_data", "opnet.data.datamodule",
              "opnet.synthesis", "opnet.parameterizations")


def test_low_layers_load_no_command_line_module() -> None:
    """Each low layer imported in turn in one fresh interpreter: the command-line modules each one loads are
    those new after its import (one loaded by an earlier layer is that layer's finding)."""
    code = ("import importlib, sys\n"
            "cli = lambda: {m for m in sys.modules if m.startswith('opnet.cli')}\n"
            f"for module in {LOW_LAYERS!r}:\n"
            "    before = cli(); importlib.import_module(module); print(module, sorted(cli() - before))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.splitlines() == [f"{m} []" for m in LOW_LAYERS]


#: what only training needs: seconds of every start of a command that does not train
TRAINING_ONLY = ("lightning", "torchmetrics", "albumentations", "torch._dynamo")


def test_the_inference_commands_load_nothing_only_training_needs() -> None:
    """predict.py, eval.py, the export and the model they load start without Lightning, torchmetrics and
    the augmentation (several seconds each start on a 2-core CPU), and so does the data module eval.py
    builds from a run's config (the same class without Lightning). No command but generation loads the mesh
    library before a mesh is made or read (about a second of every start, and of every bad setting refused)."""
    code = ("import sys, opnet.cli.predict, opnet.cli.eval, opnet.cli.export, opnet.estimator, opnet.cli.build\n"
            f"loaded = lambda: sorted(m for m in {TRAINING_ONLY!r} if m in sys.modules)\n"
            "print(loaded())\n"
            "from hydra import compose, initialize_config_dir\n"
            "from opnet.paths import config_dir\n"
            "with initialize_config_dir(config_dir=str(config_dir()), version_base='1.3'):\n"
            "    cfg = compose(config_name='train')\n"
            "data = opnet.cli.build.build_datamodule(cfg, None, train=False)\n"
            "print(type(data).__name__, loaded())\n"
            "import opnet.cli.train, opnet.cli.object\n"
            "print('trimesh' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    loaded, data_module, mesh_library = out.stdout.splitlines()
    assert loaded == "[]", f"the inference commands load {loaded}"
    assert data_module == "SceneData []", f"eval.py's data module: {data_module}"
    assert mesh_library == "False", "a command loads trimesh when imported"


def test_training_builds_the_lightning_data_module() -> None:
    """The configs' data module is a LightningDataModule for train.py, with the plain one's settings."""
    import inspect

    import lightning as L

    from conftest import compose_cfg
    from opnet.cli.build import build_datamodule
    from opnet.data.datamodule import OPNetDataModule
    from opnet.data.scene_data import SceneData

    data = build_datamodule(compose_cfg("train", ["augmentation=none"]), None, train=True)
    assert type(data) is OPNetDataModule and isinstance(data, L.LightningDataModule)
    assert isinstance(data, SceneData) and inspect.signature(OPNetDataModule) == inspect.signature(SceneData)


def test_a_physics_engine_is_imported_only_when_asked_for() -> None:
    code = (
        "import sys\n"
        "from opnet.synthesis.config import PHYSICS_ENGINES\n"
        "from opnet.synthesis.physics import ENGINES\n"
        "assert tuple(ENGINES) == PHYSICS_ENGINES, (tuple(ENGINES), PHYSICS_ENGINES)\n"
        "loaded = lambda: sorted(m for m in sys.modules if m.endswith('_engine') or m in ('mujoco', 'pybullet'))\n"
        "print(loaded())\n"
        "print(ENGINES['mujoco'].load().__name__, loaded())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "[]", "MujocoSimulator ['mujoco', 'opnet.synthesis.physics.mujoco_engine']"]  # fmt: skip


# ---- the checks find what they are for ---------------------------------------------------------
def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, body in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(body)
    return root


def test_the_module_check_finds_a_circle_inside_a_package(tmp_path: Path) -> None:
    _tree(tmp_path, {
        "toy/__init__.py": "",
        "toy/pkg/__init__.py": "from toy.pkg.a import run\n",
        "toy/pkg/a.py": "import os\n\nfrom . import b\n\ndef run():\n    return b\n",
        "toy/pkg/b.py": "from toy.pkg.c import VALUE\n",
        "toy/pkg/c.py": "try:\n    import json\nexcept ImportError:\n    pass\nelse:\n    from .a import run as VALUE\n",
        "toy/other.py": "import toy.pkg.b as b\nfrom toy.pkg import run\n",
    })  # fmt: skip
    # one package: the package-level check cannot see it
    assert circles(package_graph(tmp_path, "toy")) == []
    graph = module_graph(tmp_path, "toy")
    assert graph["toy.other"] == {"toy.pkg.b": {"toy/other.py:1"}, "toy.pkg": {"toy/other.py:2"}}
    found = import_circles(tmp_path, "toy")
    assert found == [("import circle: toy.pkg.a -> toy.pkg.b -> toy.pkg.c -> toy.pkg.a\n"
                      "  toy.pkg.a -> toy.pkg.b  (toy/pkg/a.py:3)\n"
                      "  toy.pkg.b -> toy.pkg.c  (toy/pkg/b.py:1)\n"
                      "  toy.pkg.c -> toy.pkg.a  (toy/pkg/c.py:6)")]  # fmt: skip
    # the same tree with the circle broken: clean
    (tmp_path / "toy/pkg/c.py").write_text("VALUE = 1\n")
    assert import_circles(tmp_path, "toy") == []


def test_the_old_physics_layout_is_a_circle_through_a_function_level_import(tmp_path: Path) -> None:
    # synthesis/physics.py before it became a package: the rules and make_simulator in one module,
    # which imports the engines in a function; the engines import it at module scope
    _tree(tmp_path, {
        "toy/__init__.py": "",
        "toy/physics.py": "class Base:\n    pass\n\ndef make(name):\n    from toy.physics_a import A\n    return A\n",
        "toy/physics_a.py": "from toy.physics import Base\n\nclass A(Base):\n    pass\n",
        "toy/typed.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from toy.user import X\n",
        "toy/user.py": "import toy.typed\nX = 1\n",
    })  # fmt: skip
    assert import_circles(tmp_path, "toy") == []  # nothing circles at import time
    assert import_circles(tmp_path, "toy", deferred=True) == [(
        "import circle: toy.physics -> toy.physics_a -> toy.physics\n"
        "  toy.physics -> toy.physics_a  (toy/physics.py:5)\n"
        "  toy.physics_a -> toy.physics  (toy/physics_a.py:1)")]  # fmt: skip
    # as the package now: base, engines importing only the base, the table importing them lazily
    _tree(tmp_path, {
        "toy/physics.py": "from toy.physics_base import Base\n\ndef make(name):\n    from toy.physics_a import A\n    return A\n",
        "toy/physics_base.py": "class Base:\n    pass\n",
        "toy/physics_a.py": "from toy.physics_base import Base\n\nclass A(Base):\n    pass\n",
    })  # fmt: skip
    assert import_circles(tmp_path, "toy", deferred=True) == []


def test_the_package_check_finds_a_circle_through_a_function_level_import(tmp_path: Path) -> None:
    _tree(tmp_path, {
        "toy/__init__.py": "",
        "toy/low/__init__.py": "",
        "toy/low/leaf.py": "def helper():\n    from toy.high.app import run\n    return run\n",
        "toy/high/__init__.py": "",
        "toy/high/app.py": "from ..low.leaf import helper\n\ndef run():\n    return helper\n",
        "toy/other.py": "import toy.low.leaf\n",
    })  # fmt: skip
    graph = package_graph(tmp_path, "toy")
    assert circles(graph) == [["high", "low"]]
    assert graph["other"]["low"] == {"toy/other.py:1"}
    assert import_circles(tmp_path, "toy") == []  # at import time, no circle
