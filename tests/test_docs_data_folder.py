"""The README's table of the data folder lists every folder the code writes there (it
lacked scenes/, uploaded_images/ and tmp/, which a new user finds beside the others)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def written_folders() -> set[str]:
    """The names the code joins to the data folder (``data_dir / "NAME"``)."""
    sources = [*ROOT.glob("jobs/**/*.py"), *ROOT.glob("service/**/*.py")]
    return {name for path in sources
            for name in re.findall(r'data_dir / "([\w.-]+)"', path.read_text())}


def undocumented(folders: set[str], readme: str) -> set[str]:
    section = readme[readme.index("## The data folder"):readme.index("## CLI")]
    return {name for name in folders if f"`data/{name}/" not in section}


def test_the_readme_lists_every_folder_of_the_data_folder():
    readme = (ROOT / "README.md").read_text()
    folders = written_folders()
    assert {"artifacts", "references", "tmp"} <= folders
    assert undocumented(folders, readme) == set()
    # Planted: a folder the table does not name is reported.
    assert undocumented(folders | {"caches"}, readme) == {"caches"}
