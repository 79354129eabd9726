"""The data folder's paths as the API serves them: relative to it, ``<data>/...``.

Errors stored with jobs and sweeps name files of the data folder by their absolute
path (``/srv/bench/data/references/<key>.exr``: the text of the exception that
stopped them). Whoever may read jobs would learn where the service keeps its data,
and the account layout around it; the API therefore serves those paths relative to
the data folder, while the database and the CLI on the service's machine keep them
whole. Paths outside the data folder (the installation's) are served as stored.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

#: What the data folder's own absolute path is served as.
DATA_FOLDER = "<data>"


def _data_folder_pattern(data_dir: Path) -> re.Pattern[str]:
    """The data folder's absolute path as configured and as resolved (through
    symbolic links: an exception may name either), not followed by a character of a
    file name (``/srv/data2`` is another folder)."""
    spellings = sorted({str(data_dir), str(data_dir.resolve())}, key=len, reverse=True)
    return re.compile("(?:" + "|".join(map(re.escape, spellings)) + r")(?![\w.-])")


def served(value: Any, data_dir: Path) -> Any:
    """``value`` (a text, or JSON holding texts) with the data folder's path written as
    ``<data>``."""
    pattern = _data_folder_pattern(data_dir)

    def relative(item: Any) -> Any:
        if isinstance(item, str):
            return pattern.sub(DATA_FOLDER, item)
        if isinstance(item, dict):
            return {key: relative(inner) for key, inner in item.items()}
        if isinstance(item, list):
            return [relative(inner) for inner in item]
        return item

    return relative(value)
