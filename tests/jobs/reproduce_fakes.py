"""Helpers of the reproduce figures' tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.plot import Panel


def no_drawing(drawn: list[str]) -> Any:
    """A stand-in for plot_panels that records the panels' quantities in ``drawn``: the
    PNG costs seconds and is drawn by the same helper in tests/jobs/test_reproduce.py."""
    def plot_panels(_reproduction: object, panels: list[Panel], path: Path,
                    **_kwargs: object) -> Path:
        drawn.extend(panel.quantity for panel in panels)
        return path

    return plot_panels
