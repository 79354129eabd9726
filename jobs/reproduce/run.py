"""Run one registered figure: measure it at a budget, then write its table (Markdown,
JSON) and draw its PNG into one folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.papers import paper_data
from jobs.reproduce.registry import MODES, Budget, Context, ReproduceError, get_figure
from jobs.reproduce.results import Reproduction


def reproduce(paper: str, key: str, mode: str, out_dir: Path, store: Any, settings: Any,
              progress: Any = None, budget: Budget | None = None
              ) -> tuple[Reproduction, dict[str, Path]]:
    """Figure ``key`` of ``paper`` at ``mode``'s budget (or ``budget``); returns it and
    the paths written (``figure``, ``markdown``, ``json``)."""
    spec = get_figure(paper, key)
    if mode not in MODES:
        raise ReproduceError(f"unknown mode '{mode}'; choose one of {list(MODES)}")
    ctx = Context(budget or spec.budgets[mode], store, settings, progress)
    _values, claims = paper_data(paper).of(key)
    measured = spec.measure(ctx)
    reproduction = measured.model_copy(update={
        "mode": mode if budget is None else f"{mode} (budget replaced)", "work": ctx.work,
        "claims": [c.model_dump() for c in claims]})
    paths = reproduction.write(out_dir)
    paths["figure"] = spec.draw(reproduction, out_dir / "figure.png")
    return reproduction, paths


def default_out_dir(settings: Any, paper: str, key: str) -> Path:
    """Where a figure is written unless ``--out`` says: ``<data>/reproduce/<paper>-<key>``."""
    return Path(settings.data_dir) / "reproduce" / f"{paper}-{key}"

