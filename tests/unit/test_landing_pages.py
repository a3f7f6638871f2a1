"""The README stays a landing page and each results page opens short: a reader finds the command and
the table first, the history after them (or in git)."""

from __future__ import annotations

from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

README_MAX_LINES = 150
OPENING_MAX_CHARS = 600


def opening_paragraph(page: str) -> str:
    """The first paragraph of prose of a Markdown page: not its title or another heading, a table, a
    fenced block, an HTML element (a collapsed section) or a figures marker."""
    in_fence = False
    for block in page.split("\n\n"):
        text = block.strip()
        opens_or_closes = text.count("```") % 2 == 1
        if in_fence or text.startswith("```"):
            in_fence ^= opens_or_closes
            continue
        if not text or text.startswith(("#", "|", "<", "!")):
            continue
        return text
    return ""


def test_the_readme_is_a_landing_page() -> None:
    lines = (REPO_ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md: {len(lines)} lines, at most {README_MAX_LINES}"


@pytest.mark.parametrize("page", sorted(p.relative_to(REPO_ROOT).as_posix() for p in REPO_ROOT.glob("results/*/README.md")))
def test_a_results_page_opens_with_a_short_paragraph(page: str) -> None:
    opening = opening_paragraph((REPO_ROOT / page).read_text())
    assert opening, f"{page}: no paragraph"
    assert len(opening) <= OPENING_MAX_CHARS, (f"{page}: opens with a paragraph of {len(opening)} characters "
                                               f"(at most {OPENING_MAX_CHARS}): {opening[:120]}...")


def test_the_opening_paragraph_skips_headings_tables_and_code() -> None:
    page = "# Title\n\n```\ncode\n\nmore code\n```\n\n| a | b |\n|---|---|\n\n<details>\n\nThe text.\n\nLater."
    assert opening_paragraph(page) == "The text."
    long = "# T\n\n" + "word " * 200
    assert len(opening_paragraph(long)) > OPENING_MAX_CHARS
