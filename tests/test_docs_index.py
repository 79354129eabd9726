"""Every page under docs/ is listed in the index of docs/design.md."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def indexed_pages(design: str) -> set[str]:
    """The pages the index table of docs/design.md lists (its first column)."""
    return set(re.findall(r"^\| `([\w.-]+\.md)` \|", design, flags=re.MULTILINE))


def unindexed(pages: set[str], design: str) -> set[str]:
    return pages - {"design.md"} - indexed_pages(design)


def test_every_docs_page_is_in_the_design_index():
    design = (DOCS / "design.md").read_text()
    pages = {path.name for path in DOCS.glob("*.md")}
    assert unindexed(pages, design) == set()
    # planted: a page the index does not list is reported
    assert unindexed(pages | {"new_page.md"}, design) == {"new_page.md"}
