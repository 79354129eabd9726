"""Every dashboard screenshot in docs/images/ says how it was made: docs/dashboard.md's
table names the browser test that takes it and the file that test writes."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROW = re.compile(r"^\| `(dashboard_[\w-]+\.png)` \| `([\w.]+\.py)(?:::(\w+))?`[^|]*\| "
                 r"`([\w.-]+\.png)` \|$", flags=re.MULTILINE)


def provenance(page: str) -> dict[str, tuple[str, str | None, str]]:
    """docs/images name -> (test file, test function or None, test-artifacts name)."""
    return {image: (module, function or None, artifact)
            for image, module, function, artifact in ROW.findall(page)}


def unexplained(images: set[str], page: str) -> list[str]:
    """Screenshots without a row, and rows whose test does not write their file."""
    rows = provenance(page)
    problems = [f"{image}: no row" for image in sorted(images - rows.keys())]
    for image, (module, function, artifact) in rows.items():
        source = (ROOT / "tests" / "service" / module).read_text()
        if function is not None:
            start = source.index(f"def {function}(")
            end = source.find("\ndef ", start + 1)
            source = source[start:end if end > 0 else None]
        if f'ARTIFACTS / "{artifact}"' not in source:
            test = f"{module}::{function}" if function else module
            problems.append(f"{image}: {test} does not write {artifact}")
    return problems


def test_every_dashboard_screenshot_names_the_test_that_took_it():
    page = (ROOT / "docs" / "dashboard.md").read_text()
    images = {path.name for path in (ROOT / "docs" / "images").glob("dashboard_*.png")}
    shown = set(re.findall(r"\]\(images/(dashboard_[\w-]+\.png)\)", page))
    assert shown <= images
    assert unexplained(images, page) == []
    # Planted: a screenshot without a row, and a row naming a test that takes another file.
    assert unexplained(images | {"dashboard_new.png"}, page) == ["dashboard_new.png: no row"]
    wrong = page.replace("| `dashboard-history.png` |", "| `dashboard-jobs.png` |")
    assert unexplained(images, wrong) == [
        "dashboard_history.png: test_dashboard_history.py does not write dashboard-jobs.png"]
