"""Only the edge reads ``conf/``: the entry points (``opnet.cli``), what runs above them (studies, analyses and
tools that drive whole runs) and the refinement's settings loader. A low layer (geometry, data, models, the
generator, the parameterizations, the deployment runtime) is given its settings, never opens the config folder
itself, so that it runs the same from an installed package, a test's temporary config or an ONNX export."""

from __future__ import annotations

import ast
from pathlib import Path

from opnet.paths import REPO_ROOT

SRC = REPO_ROOT / "src"
#: packages (and modules) that may read the config folder
READERS = ("opnet.cli", "opnet.studies", "opnet.analysis", "opnet.tools", "opnet.refine.settings", "opnet.paths")
#: what reading it looks like: the folder's path, or Hydra composing from it
CALLS = {"config_dir", "initialize_config_dir", "initialize", "compose"}


def _module(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _readers_of_conf(path: Path) -> list[str]:
    """``name:line`` of each call of :data:`CALLS`, and of each literal ``"conf"`` path, in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""
            if name in CALLS:
                found.append(f"{name}():{node.lineno}")
        elif isinstance(node, ast.Constant) and node.value in ("conf", "conf/"):
            found.append(f"'conf':{node.lineno}")
    return found


def test_only_the_edge_reads_the_config_folder() -> None:
    below = {}
    for path in sorted(SRC.rglob("*.py")):
        module = _module(path)
        if any(module == r or module.startswith(r + ".") for r in READERS):
            continue
        found = _readers_of_conf(path)
        if found:
            below[module] = found
    assert not below, f"modules below the entry points read conf/: {below}"


def test_the_scan_sees_a_reader() -> None:
    """The scan is not blind: the refinement's loader and the presets of the studies are found."""
    assert _readers_of_conf(SRC / "opnet" / "refine" / "settings.py")
    assert _readers_of_conf(SRC / "opnet" / "studies" / "presets.py")
