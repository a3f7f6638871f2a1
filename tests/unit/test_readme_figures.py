"""The figures of the README and of the docs pages equal the committed results files
(scripts/dev/readme_figures.py)."""

from __future__ import annotations

import csv
import importlib.util
import json
import re
import shutil
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("readme_figures", REPO_ROOT / "scripts" / "dev" / "readme_figures.py")
figures = importlib.util.module_from_spec(spec)
spec.loader.exec_module(figures)

README = REPO_ROOT / "README.md"
DOCS = REPO_ROOT / "docs"
# numbers written by hand outside the blocks that a test of their own asserts: the evaluator
# against the official tool (tests/unit/test_metric_bregier.py)
ASSERTED_ELSEWHERE = ("AP 0.797872",)
HAND_WRITTEN_AP = re.compile(r"\bAP (0\.\d{2,}|\*\*0\.)")


def test_readme_figures_equal_the_results_files() -> None:
    readme = README.read_text()
    assert figures.render(readme) == readme, "README figures drifted: run python scripts/dev/readme_figures.py"


def test_docs_figures_equal_the_results_files() -> None:
    pages = figures.docs_pages()
    assert DOCS / "method.md" in pages and DOCS / "data.md" in pages
    for path, page in pages.items():
        assert figures.render_page(page) == page, f"{path} figures drifted: run python scripts/dev/readme_figures.py"


def test_every_block_sits_in_a_page_and_links_from_its_own_folder() -> None:
    texts = {README: README.read_text(), **figures.docs_pages()}
    where: dict[str, list[str]] = {}
    for path, text in texts.items():
        for name in figures.blocks_of(text, str(path)):
            where.setdefault(name, []).append(path.name)
    assert set(where) == set(figures.BLOCKS)
    # the same block written into the README and into a docs page: links one folder up there
    assert "](results/quickstart/console_tail.txt)" in figures.render_text("<!-- figures:quickstart -->\n<!-- /figures:quickstart -->")
    page = figures.render_page("<!-- figures:quickstart -->\n<!-- /figures:quickstart -->")
    assert "](../results/quickstart/console_tail.txt)" in page
    assert 'src="../results/ceiling/ceiling.png"' in figures.render_page("<!-- figures:pictures_method -->\n<!-- /figures:pictures_method -->")


def test_quickstart_figure_is_the_recorded_run() -> None:
    q = json.loads((REPO_ROOT / "results" / "quickstart" / "summary.json").read_text())
    section = (DOCS / "results.md").read_text().split("<!-- figures:quickstart -->")[1]
    assert f"test AP {q['ap']:.4f}" in section
    # the README's headline row of the quickstart, rounded
    assert f"test AP **{q['ap']:.3f}**" in README.read_text().split("<!-- figures:headline -->")[1]
    # the console's last lines, recorded by the same run, print the same AP
    tail = (REPO_ROOT / "results" / "quickstart" / "console_tail.txt").read_text()
    assert f"AP {q['ap']:.4f}" in tail and tail.rstrip().splitlines()[-1].startswith("predictions")


def test_a_changed_result_fails_the_check(tmp_path: Path) -> None:
    results = tmp_path / "results"
    shutil.copytree(REPO_ROOT / "results", results)
    path = results / "dense" / "dense.csv"  # a row of the README's headline table
    rows = list(csv.DictReader(path.open()))
    row = next(r for r in rows if r["config"] == figures.DENSE_HEADLINE)
    row["ap"] = str(float(row["ap"]) - 0.1)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    readme = README.read_text()
    assert figures.render(readme, results) != readme
    readme_copy = tmp_path / "README.md"
    readme_copy.write_text(readme)
    assert figures.main(["--check", "--readme", str(readme_copy), "--results", str(results)]) == 1


def test_a_changed_result_of_a_docs_page_fails_the_check(tmp_path: Path) -> None:
    """The framing table sits in docs/data.md only: a changed AP there fails the check, and the
    render writes it into the page (the README stays as it is)."""
    assert "<!-- figures:framing -->" in (DOCS / "data.md").read_text()
    assert "<!-- figures:framing -->" not in README.read_text()
    results = tmp_path / "results"
    shutil.copytree(REPO_ROOT / "results", results)
    path = results / "framing" / "framing.csv"
    text = path.read_text()
    rows = list(csv.DictReader(text.splitlines()))
    path.write_text(text.replace(rows[0]["ap"], "0.1234", 1))
    readme, docs = tmp_path / "README.md", tmp_path / "docs"
    shutil.copy(README, readme)
    shutil.copytree(DOCS, docs)
    args = ["--readme", str(readme), "--docs", str(docs), "--results", str(results)]
    assert figures.main(["--check", *args]) == 1
    assert figures.main(args) == 0  # renders (and draws the ceiling chart into the copy of results/)
    assert "**0.1234**" in (docs / "data.md").read_text() and readme.read_text() == README.read_text()
    assert figures.main(["--check", *args]) == 0


def _hand_written_ap(text: str) -> list[str]:
    outside = figures.BLOCK.sub("", text)
    for number in ASSERTED_ELSEWHERE:
        outside = outside.replace(number, "")
    return [m.group(0) for m in HAND_WRITTEN_AP.finditer(outside)]


def test_every_results_number_sits_in_a_rendered_block() -> None:
    """Outside the figures blocks, the README's results section and the docs pages (each of them
    holds results next to its topic) hold no measured number of the tables (an AP written by hand,
    e.g. 'AP 0.81', would escape the check)."""
    sections = re.split(r"^## Results\b.*$", README.read_text(), flags=re.MULTILINE)
    assert len(sections) == 2, "the README has one '## Results ...' section"
    section = sections[1].split("\n## ")[0]
    assert "<!-- figures:headline -->" in section
    assert not _hand_written_ap(section), "a hand-written AP outside the rendered blocks of the README"
    assert "<!-- figures:quickstart -->" in (DOCS / "results.md").read_text()
    for path, page in figures.docs_pages().items():
        assert not _hand_written_ap(page), f"a hand-written AP outside the rendered blocks of {path}"
    assert _hand_written_ap("<!-- figures:ab -->\n<!-- /figures:ab -->\nreached AP 0.81 here") == ["AP 0.81"]


def test_unknown_or_missing_blocks_are_errors() -> None:
    with pytest.raises(ValueError, match="missing"):
        figures.render("no blocks here")
    readme = README.read_text()
    # a block that sits in no page at all (here: the docs pages given are none)
    with pytest.raises(ValueError, match=r"missing \[.*'framing'"):
        figures.render(readme, pages={})
    with pytest.raises(ValueError, match="unknown"):
        figures.render_page("<!-- figures:nope -->\n<!-- /figures:nope -->\n")
    with pytest.raises(ValueError, match="without their pair"):
        figures.render_page("<!-- figures:ab -->\nno end\n")


def test_quickstart_seeds_table_gives_mean_and_sd_per_precision_path(tmp_path: Path) -> None:
    """results/quickstart/seeds.csv (scripts/experiments/quickstart/quickstart_seeds.py) renders one row per CPU and
    precision path with the sample mean ± sd over its seeds; runs that generated data are left out
    of the time per run."""
    results = tmp_path / "results"
    shutil.copytree(REPO_ROOT / "results", results)
    fields = ["cpu", "native_bf16", "precision_path", "seed", "ap", "map", "f1", "found", "wall_s",
              "with_generation", "torch", "date", "command"]
    rows = [["CPU A", "True", "bf16", s, ap, 0, 0, 0, wall, gen, "2.13.0", "2026-11-25", "c"]
            for s, ap, wall, gen in ((0, 0.80, 500, True), (1, 0.82, 200, False), (2, 0.84, 220, False))]
    rows += [["CPU A", "True", "fp32", 0, 0.70, 0, 0, 0, 300, False, "2.13.0", "2026-11-25", "c"]]
    with (results / "quickstart" / "seeds.csv").open("w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(fields)
        writer.writerows(rows)
    block = figures.block_quickstart(results)
    bf16 = next(line for line in block.splitlines() if "**bf16**" in line)
    assert "**0.820 ± 0.020**" in bf16 and "0.800 – 0.840" in bf16 and "3 min 30 s" in bf16
    fp32 = next(line for line in block.splitlines() if "**fp32**" in line)
    assert "**0.700 ± —**" in fp32
