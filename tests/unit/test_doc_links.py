"""Every relative link of README.md and docs/*.md resolves: the file (or folder) exists, and an
anchor into a Markdown file names one of its headings (GitHub's slugs). External links are skipped.
The README's "what next" table is a selection of docs/commands.md's table, command for command
(tests/integration/test_readme_commands.py runs every row of that table)."""

from __future__ import annotations

import importlib.util
import re
import shutil
from pathlib import Path
from urllib.parse import unquote

from opnet.paths import REPO_ROOT

FENCE = re.compile(r"^```.*?^```", re.DOTALL | re.MULTILINE)
CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")  # [text](target "title")
IMG = re.compile(r"<img\b[^>]*\bsrc=[\"']([^\"']+)[\"']", re.IGNORECASE)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.MULTILINE)


def pages(root: Path = REPO_ROOT) -> list[Path]:
    """README.md and the docs pages."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: its text lowercased, punctuation but ``-`` and ``_`` dropped
    (letters of any script stay), spaces turned into ``-``."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading anchors by its text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of a Markdown file's headings (a repeated heading gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    out = set()
    for heading in HEADING.findall(FENCE.sub("", page.read_text())):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(page: Path) -> list[str]:
    """The link and image targets of a Markdown page, outside code."""
    text = CODE.sub("", FENCE.sub("", page.read_text()))
    return LINK.findall(text) + IMG.findall(text)


def broken_links(files: list[Path]) -> list[str]:
    """``file: target (why)`` for every relative link of ``files`` that does not resolve."""
    broken = []
    for page in files:
        for target in links(page):
            if re.match(r"[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / unquote(path)).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and unquote(anchor) not in anchors(dest):
                broken.append(f"{page.name}: {target} (no such heading in {dest.name})")
    return broken


def test_every_relative_link_resolves() -> None:
    files = pages()
    assert len(files) > 5 and all(f.is_file() for f in files)
    assert sum(len(links(f)) for f in files) > 50  # the pages do link: the parser finds them
    assert broken_links(files) == []


def test_every_docs_page_is_in_the_index_and_reachable_from_the_readme() -> None:
    index = set(links(REPO_ROOT / "docs" / "README.md"))
    readme = set(links(REPO_ROOT / "README.md"))
    assert "docs/README.md" in readme
    for page in sorted((REPO_ROOT / "docs").glob("*.md")):
        if page.name != "README.md":
            assert page.name in index, f"docs/{page.name} is not in the index docs/README.md"


def test_github_slugs() -> None:
    assert slug("The paper's formulation, or our measured best") == "the-papers-formulation-or-our-measured-best"
    assert slug("Results (this 2-core CPU machine, no GPU)") == "results-this-2-core-cpu-machine-no-gpu"
    assert slug("Siléane layout") == "siléane-layout"
    assert slug("ONNX export and the runtime without PyTorch") == "onnx-export-and-the-runtime-without-pytorch"
    assert slug("`data.fit` and snake_case — a dash") == "datafit-and-snake_case--a-dash"


def test_a_broken_link_fails(tmp_path: Path) -> None:
    """The pages copied beside the rest of the repository (linked, not copied): clean, then one
    missing file, one missing heading and one missing picture are each reported."""
    for entry in REPO_ROOT.iterdir():
        if entry.name not in ("README.md", "docs", ".git"):
            (tmp_path / entry.name).symlink_to(entry)
    shutil.copy(REPO_ROOT / "README.md", tmp_path / "README.md")
    shutil.copytree(REPO_ROOT / "docs", tmp_path / "docs")
    assert broken_links(pages(tmp_path)) == []

    data = tmp_path / "docs" / "data.md"
    data.write_text(data.read_text() + "\n[gone](formats.md#no-such-heading) and [lost](../results/lost.csv)\n")
    readme = tmp_path / "README.md"
    readme.write_text(readme.read_text() + '\n<img src="results/lost.png"> [ok](https://example.org/x)\n')
    assert sorted(broken_links(pages(tmp_path))) == [
        "README.md: results/lost.png (no such file)",
        "data.md: ../results/lost.csv (no such file)",
        "data.md: formats.md#no-such-heading (no such heading in formats.md)",
    ]


def test_readme_task_table_is_a_selection_of_the_commands_page() -> None:
    path = REPO_ROOT / "tests" / "integration" / "test_readme_commands.py"
    spec = importlib.util.spec_from_file_location("readme_commands", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rows = module.readme_commands()  # asserts the README's rows are rows of docs/commands.md
    readme_rows = module.task_table(REPO_ROOT / "README.md")
    assert 5 <= len(readme_rows) < len(rows)
