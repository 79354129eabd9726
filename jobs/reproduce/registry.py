"""The figures ``nirc-bench reproduce`` knows, by paper and figure key.

A paper is a :class:`Paper` (a short key, its title, its data file under ``papers/``);
a figure is a :class:`FigureSpec` registered by its module, one module per figure named
``<paper>_<figure>.py`` in this package (found by :func:`figure_modules`, imported on
first use). Another paper's figures slot in as a :class:`Paper` here and one module per
figure.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from jobs.reproduce.results import Reproduction

#: The budgets a figure is rendered at: ``quick`` (minutes on 2 cores) and ``full``.
MODES = ("quick", "full")


class ReproduceError(ValueError):
    """A figure or paper that is not registered, or a budget a figure does not have."""


@dataclass(frozen=True)
class Paper:
    key: str            # the command's word for it: ``nirc-bench reproduce <key> ...``
    title: str
    reference: str      # its tag in docs/references.md
    data_file: str      # its published numbers, under jobs/reproduce/papers/


@dataclass(frozen=True)
class Budget:
    """What one run of a figure renders: image size, K seeds of F one-spp frames, the
    reference's spp, the `grid-cache` preset (renderers/methods/grid_cache.py,
    ``GRID_PRESETS``), and why this size and preset (stated in the figure's table)."""

    resolution: int
    seeds: int
    frames: int
    ref_spp: int
    grid_preset: str
    why: str
    values: tuple[float, ...] = ()   # the figure's swept values (its x axis), if any


@dataclass(frozen=True)
class Context:
    """What a figure renders with: the budget, the store and settings, the progress."""

    budget: Budget
    store: Any
    settings: Any
    progress: Callable[[str, int, int], None] | None = None
    work: dict[str, int] = field(default_factory=dict)   # sweep points rendered / reused


@dataclass(frozen=True)
class FigureSpec:
    paper: str                     # a key of PAPERS
    key: str                       # e.g. 'fig7', 'table1'
    title: str
    budgets: Mapping[str, Budget]  # by mode (MODES)
    measure: Callable[[Context], Reproduction]
    draw: Callable[[Reproduction, Path], Path]


PAPERS: dict[str, Paper] = {
    "vt": Paper("vt", "Optimizing Path Termination for Radiance Caching Through Explicit "
                      "Variance Trading", "VTT24", "variance_trading.toml"),
    "nirc": Paper("nirc", "Neural Two-Level Monte Carlo Real-Time Rendering", "DKHD24",
                  "nirc.toml"),
    "nvc": Paper("nvc", "Neural Visibility Cache for Real-Time Light Sampling", "BM25",
                 "nvc.toml"),
}

def figure_modules() -> list[str]:
    """The modules that register figures: this package's ``<paper>_<figure>.py`` files,
    ``<paper>`` a key of :data:`PAPERS`, ``<figure>`` ``fig<N>`` or ``table<N>``."""
    pattern = re.compile(rf"^({'|'.join(PAPERS)})_(fig|table)\d+\.py$")
    here = Path(__file__).parent
    return sorted(f"{__package__}.{path.stem}" for path in here.iterdir()
                  if pattern.match(path.name))

_FIGURES: dict[tuple[str, str], FigureSpec] = {}


def register(spec: FigureSpec) -> FigureSpec:
    if spec.paper not in PAPERS:
        raise ValueError(f"figure {spec.key}: unknown paper {spec.paper!r}")
    if set(spec.budgets) != set(MODES):
        raise ValueError(f"figure {spec.paper} {spec.key}: budgets must be {MODES}")
    _FIGURES[(spec.paper, spec.key)] = spec
    return spec


def figures() -> list[FigureSpec]:
    """Every registered figure, by paper and key."""
    for module in figure_modules():
        importlib.import_module(module)
    return sorted(_FIGURES.values(), key=lambda f: (f.paper, f.key))


def get_figure(paper: str, key: str) -> FigureSpec:
    """The figure ``key`` of ``paper``; ReproduceError naming the choices otherwise."""
    known = figures()
    if paper not in PAPERS:
        raise ReproduceError(f"unknown paper '{paper}'; choose one of {sorted(PAPERS)}")
    for spec in known:
        if (spec.paper, spec.key) == (paper, key):
            return spec
    choices = [spec.key for spec in known if spec.paper == paper]
    raise ReproduceError(f"unknown figure '{key}' of paper '{paper}'; choose one of {choices}")
