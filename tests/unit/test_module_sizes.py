"""No module of the package over 500 lines: a module that grows past it holds more than one idea, and a
newcomer reading it for one of them reads the others too (split it where docs/code.md would name two pieces)."""

from __future__ import annotations

from opnet.paths import REPO_ROOT

MAX_LINES = 500


def test_no_module_over_the_limit() -> None:
    src = REPO_ROOT / "src" / "opnet"
    sizes = {str(p.relative_to(src)): len(p.read_text().splitlines()) for p in src.rglob("*.py")}
    assert len(sizes) > 50  # the scan sees the package
    over = {name: n for name, n in sizes.items() if n > MAX_LINES}
    assert not over, f"modules over {MAX_LINES} lines: {over}"
