"""No import circles between the packages of ``src/opnet``: each package (``cli``,
``data``, ``synthesis``, ...) and each top-level module (``inference``, ``system``, ...) is one
node; every ``import`` counts, at module level or inside a function, as both make the two
depend on each other. A circle means a low layer reaches up into a high one (the inference engine
into the command line, the generator into the console), which is what this test forbids."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

SRC = REPO_ROOT / "src"


def _module_name(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _node(module: str, top: str) -> str | None:
    """The graph node of a dotted module name: ``top.<first part>``; None outside ``top``."""
    parts = module.split(".")
    if parts[0] != top or len(parts) < 2:
        return None
    return parts[1]


def _imported(tree: ast.AST, module: str, is_package: bool) -> list[str]:
    """Every module name an AST imports (``from a import b`` gives ``a`` and ``a.b``)."""
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolved against this module's package
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            names += [origin] + [f"{origin}.{a.name}" for a in node.names]
    return names


def package_graph(src: Path, top: str) -> dict[str, dict[str, set[str]]]:
    """node -> node it imports -> the files (relative to ``src/top``) whose imports make the edge."""
    graph: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for path in sorted((src / top).rglob("*.py")):
        module = _module_name(path, src)
        here = _node(module, top)
        if here is None:
            continue  # the package's own __init__
        for name in _imported(ast.parse(path.read_text(), str(path)), module, path.name == "__init__.py"):
            there = _node(name, top)
            if there is not None and there != here:
                graph[here][there].add(str(path.relative_to(src / top)))
    return graph


def circles(graph: dict[str, dict[str, set[str]]]) -> list[list[str]]:
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
    return found


def _describe(graph: dict[str, dict[str, set[str]]], component: list[str]) -> str:
    edges = [f"{a} -> {b} ({', '.join(sorted(graph[a][b]))})" for a in component for b in sorted(graph[a])
             if b in component]  # fmt: skip
    return "circle " + " / ".join(component) + ":\n  " + "\n  ".join(edges)


def test_no_circle_between_the_packages_of_opnet() -> None:
    graph = package_graph(SRC, "opnet")
    assert len(graph) > 10  # the walk saw the packages
    found = circles(graph)
    assert not found, "\n".join(_describe(graph, c) for c in found)


def test_the_check_finds_a_circle_through_a_function_level_import(tmp_path: Path) -> None:
    pkg = tmp_path / "toy"
    for name, body in {
        "__init__.py": "",
        "low/__init__.py": "",
        "low/leaf.py": "def helper():\n    from toy.high.app import run\n    return run\n",
        "high/__init__.py": "",
        "high/app.py": "from ..low.leaf import helper\n\ndef run():\n    return helper\n",
        "other.py": "import toy.low.leaf\n",
    }.items():  # fmt: skip
        (pkg / name).parent.mkdir(parents=True, exist_ok=True)
        (pkg / name).write_text(body)
    graph = package_graph(tmp_path, "toy")
    assert circles(graph) == [["high", "low"]]
    assert graph["other"]["low"] == {"other.py"}


@pytest.mark.parametrize("module", ["opnet.inference", "opnet.system", "opnet.data.datamodule",
                                    "opnet.synthesis", "opnet.parameterizations"])
def test_low_layers_load_no_command_line_module(module: str) -> None:
    code = f"import sys, {module}; print(sorted(m for m in sys.modules if m.startswith('opnet.cli')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "[]", f"{module} loads {out.stdout.strip()}"
