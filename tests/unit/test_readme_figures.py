"""The README's figures equal the committed results files (scripts/readme_figures.py)."""

from __future__ import annotations

import csv
import importlib.util
import json
import re
import shutil
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("readme_figures", REPO_ROOT / "scripts" / "readme_figures.py")
figures = importlib.util.module_from_spec(spec)
spec.loader.exec_module(figures)

README = REPO_ROOT / "README.md"


def test_readme_figures_equal_the_results_files() -> None:
    readme = README.read_text()
    assert figures.render(readme) == readme, "README figures drifted: run python scripts/readme_figures.py"


def test_quickstart_figure_is_the_recorded_run() -> None:
    q = json.loads((REPO_ROOT / "results" / "quickstart" / "summary.json").read_text())
    section = README.read_text().split("<!-- figures:quickstart -->")[1]
    assert f"test AP {q['ap']:.4f}" in section
    # the console's last lines, recorded by the same run, print the same AP
    tail = (REPO_ROOT / "results" / "quickstart" / "console_tail.txt").read_text()
    assert f"AP {q['ap']:.4f}" in tail and tail.rstrip().splitlines()[-1].startswith("predictions")


def test_a_changed_result_fails_the_check(tmp_path: Path) -> None:
    results = tmp_path / "results"
    shutil.copytree(REPO_ROOT / "results", results)
    path = results / "learning" / "learning.csv"
    rows = list(csv.DictReader(path.open()))
    rows[0]["ap"] = str(float(rows[0]["ap"]) - 0.1)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    readme = README.read_text()
    assert figures.render(readme, results) != readme
    readme_copy = tmp_path / "README.md"
    readme_copy.write_text(readme)
    assert figures.main(["--check", "--readme", str(readme_copy), "--results", str(results)]) == 1


def test_every_results_number_sits_in_a_rendered_block() -> None:
    """Outside the figures blocks, the results section holds no measured number of the tables
    (an AP written by hand, e.g. 'AP 0.81', would escape the check)."""
    section = README.read_text().split("## Results and figures")[1].split("\n## ")[0]
    outside = figures.BLOCK.sub("", section)
    assert not re.search(r"\bAP (0\.\d{2,}|\*\*0\.)", outside.replace("AP 0.797872", "")), \
        "a hand-written AP outside the rendered blocks"


def test_unknown_or_missing_blocks_are_errors() -> None:
    with pytest.raises(ValueError, match="missing"):
        figures.render("no blocks here")
