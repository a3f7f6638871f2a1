"""The product speaks of itself only: no tracked file of the code, configs, docs, tests, scripts,
results or models cites a number of a tracker the user has no access to ("issue" followed by a
number). Each sentence says what it means instead. And every Markdown file that a docstring or a
comment of the code, configs, tests or scripts cites is in the repository, with the heading it
names."""

from __future__ import annotations

import ast
import importlib.util
import io
import re
import shutil
import subprocess
import tokenize
from pathlib import Path
from types import ModuleType

import pytest

from opnet.paths import REPO_ROOT

CHECKED = ["src", "conf", "docs", "tests", "scripts", "results", "models", "README.md"]

# Built from pieces so that this file does not match its own pattern.
_WORD = "iss" + "ue"
TRACKER_REF = re.compile(r"\b" + _WORD + r"s?\s*#?\s*[0-9]", re.IGNORECASE)


def _tracked_files(folders: list[str] = CHECKED) -> list[str]:
    if shutil.which("git") is None or not (REPO_ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    out = subprocess.run(["git", "ls-files", "-z", "--", *folders], cwd=REPO_ROOT, check=True,
                         capture_output=True).stdout
    return [name for name in out.decode().split("\0") if name and ".egg-info/" not in name]


def _tracked_texts(folders: list[str] = CHECKED) -> dict[str, str]:
    """name -> text of the tracked text files under ``folders`` (binary files left out)."""
    texts = {}
    for name in _tracked_files(folders):
        path = REPO_ROOT / name
        if not path.is_file():
            continue  # deleted in the working tree, not yet committed
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue  # binary (pictures, arrays)
        texts[name] = data.decode("utf-8", errors="replace")
    return texts


def test_no_tracker_numbers_in_tracked_files() -> None:
    hits = []
    for name, text in _tracked_texts().items():
        for lineno, line in enumerate(text.splitlines(), 1):
            if TRACKER_REF.search(line):
                hits.append(f"{name}:{lineno}: {line.strip()[:120]}")
    assert not hits, "tracker numbers in the product (say what is meant instead):\n" + "\n".join(hits)


# ---- Markdown files cited by docstrings and comments ---------------------------------------------

#: where the citations are checked: the code, the configs, the tests and the scripts
CITING = ["src", "conf", "tests", "scripts"]
#: a file name or a path ending in ``.md`` (not the tail of a longer path, nor a file under a
#: placeholder such as ``<out>/`` or ``$DIR/``), then optionally ``#anchor`` or a quoted heading
MD_REF = re.compile(r"(?<![\w./<>{}$-])((?:[\w.-]+/)*[\w-]+\.md)(?!\w|\.\w)"
                    r"(?:#([\w-]+)|[ \t]+\"([^\"\n]+)\")?")
#: a section sign and its number, alone or right after a citation
SECTION = re.compile(r"§\s*(\d+(?:\.\d+)*)")
SECTION_AFTER = re.compile(r"\s*(§\s*(\d+(?:\.\d+)*))")
#: a command-line option right before a path: the path is an argument (a file to write), not a citation
OPTION_BEFORE = re.compile(r"--[\w-]+[ =]$")
HASH_COMMENT = re.compile(r"(?:^|\s)#(.*)$")
MD_NAME = re.compile(r"[\w.-]+\.md\b")


def _doc_links() -> ModuleType:
    """tests/unit/test_doc_links.py, for its headings and GitHub's slugs of them."""
    path = REPO_ROOT / "tests" / "unit" / "test_doc_links.py"
    spec = importlib.util.spec_from_file_location("doc_links", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _blocks(lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """Comment lines ``(line number, text)`` joined into blocks of consecutive lines."""
    blocks: list[tuple[int, str]] = []
    for lineno, text in lines:
        if blocks and lineno == blocks[-1][0] + blocks[-1][1].count("\n") + 1:
            blocks[-1] = (blocks[-1][0], blocks[-1][1] + "\n" + text)
        else:
            blocks.append((lineno, text))
    return blocks


def prose(name: str, text: str) -> tuple[list[tuple[int, str]], str]:
    """The docstrings and comments of a file as ``(first line, text)`` blocks, and the rest of it
    (its code). Python: docstrings and ``#`` comments; YAML and shell: ``#`` comments; other files
    are all code."""
    if name.endswith(".py"):
        docstrings = {}
        for node in ast.walk(ast.parse(text)):
            body = getattr(node, "body", None)
            if (isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
                    and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):  # fmt: skip
                docstrings[(body[0].lineno, body[0].col_offset)] = body[0].value.value
        comments, code = [], []
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.COMMENT:
                comments.append((tok.start[0], tok.string[1:]))
            elif tok.start not in docstrings:
                code.append(tok.string)
        return [(line, doc) for (line, _), doc in docstrings.items()] + _blocks(comments), " ".join(code)
    if name.endswith((".yaml", ".yml", ".sh")):
        comments, code = [], []
        for lineno, line in enumerate(text.splitlines(), 1):
            match = HASH_COMMENT.search(line)
            if match:
                comments.append((lineno, match.group(1)))
            code.append(line[: match.start()] if match else line)
        return _blocks(comments), "\n".join(code)
    return [], text


def unresolved_citations(root: Path, files: dict[str, str]) -> list[str]:
    """``file:line: citation (why)`` for every citation of a Markdown file in the docstrings and
    comments of ``files`` (name relative to ``root`` -> text) that does not resolve.

    A bare name is a page of ``root/docs`` or a file of ``root``, a path is relative to ``root``;
    an anchor or a quoted heading must be a heading of that file (GitHub's slug); a section number
    ``§n`` must follow a citation of a file whose headings are numbered that way. A file the code
    of the same file names (a file it writes, such as a report) and a path after a command-line
    option are not citations: they need not exist, unless they come with a heading or a section
    number."""
    doc_links = _doc_links()
    bad = []
    for name, text in sorted(files.items()):
        blocks, code = prose(name, text)
        handled = set(MD_NAME.findall(code))
        for first, block in blocks:
            attached = set()
            for match in MD_REF.finditer(block):
                ref, anchor, heading = match.groups()
                section = SECTION_AFTER.match(block, match.end())
                if section is not None:
                    attached.add(section.start(1))
                where = f"{name}:{first + block.count(chr(10), 0, match.start())}: {match.group(0)}"
                candidates = [root / ref] if "/" in ref else [root / "docs" / ref, root / ref]
                targets = [path for path in candidates if path.is_file()]
                plain = anchor is None and heading is None and section is None
                if not targets:
                    if not (plain and (ref.rsplit("/", 1)[-1] in handled
                                       or OPTION_BEFORE.search(block, 0, match.start()))):
                        bad.append(f"{where} (no such file in the repository)")
                    continue
                pages = " or ".join(str(path.relative_to(root)) for path in targets)
                if heading is not None:
                    anchor = doc_links.slug(heading)
                if anchor is not None and not any(anchor in doc_links.anchors(path) for path in targets):
                    bad.append(f"{where} (no such heading in {pages})")
                if section is not None:
                    number = re.compile(re.escape(section.group(2)) + r"[.\s]")
                    headings = [h for path in targets
                                for h in doc_links.HEADING.findall(doc_links.FENCE.sub("", path.read_text()))]
                    if not any(number.match(h) for h in headings):
                        bad.append(f"{where} {section.group(1)} ({pages} numbers no such section)")
            for section in SECTION.finditer(block):
                if section.start() not in attached:
                    line = first + block.count("\n", 0, section.start())
                    bad.append(f"{name}:{line}: {section.group(0)} (a section number that names no file)")
    return bad


def test_docstring_references_resolve() -> None:
    files = _tracked_texts(CITING)
    assert len(files) > 200 and all(not name.startswith("docs/") for name in files)
    bad = unresolved_citations(REPO_ROOT, files)
    assert not bad, "citations of files or headings that the repository lacks:\n" + "\n".join(bad)


def test_a_citation_that_does_not_resolve_fails(tmp_path: Path) -> None:
    """On a small tree: good citations pass; a missing file, a missing heading, a section number
    the page does not number and a section number of no file are each reported."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "page.md").write_text("# Page\n\n## Pose distance\n\n## 2.3 Matching\n")
    (tmp_path / "README.md").write_text("# Top\n\n## Documentation\n")
    good = ('"""Cites docs/page.md#pose-distance, page.md "Pose distance", README.md#documentation,\n'
            'docs/page.md §2.3 and the report ``out.md`` it writes."""\n\nNAME = "out.md"\n'
            "# a path after an option: --out results/new.md\n")
    bad = ('"""Cites notes.md §4, docs/page.md#no-such-heading and docs/page.md §3."""\n'
           "# and §2.6 alone\n")
    conf = "# the paper's loss (notes.md)\nkey: 1  # page.md §1\n"
    assert unresolved_citations(tmp_path, {"good.py": good}) == []
    assert unresolved_citations(tmp_path, {"bad.py": bad, "conf.yaml": conf}) == [
        "bad.py:1: notes.md (no such file in the repository)",
        "bad.py:1: docs/page.md#no-such-heading (no such heading in docs/page.md)",
        "bad.py:1: docs/page.md §3 (docs/page.md numbers no such section)",
        "bad.py:2: §2.6 (a section number that names no file)",
        "conf.yaml:1: notes.md (no such file in the repository)",
        "conf.yaml:2: page.md §1 (docs/page.md numbers no such section)",
    ]
