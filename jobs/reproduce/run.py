"""Run one registered figure: measure it at a budget, then write its table (Markdown,
JSON), draw its PNG and record its provenance (with what it took: wall and CPU seconds,
the machine's load) into one folder. The folder holds a marker while the run lasts
(jobs/record/reproduction_marker.py): retention leaves it alone, and a second run into it
is refused."""

from __future__ import annotations

import os
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from jobs.protocol.provenance import git_commit, library_versions
from jobs.record.reproduction_folders import JOB_PREFIX, PROVENANCE
from jobs.record.reproduction_marker import running_marker
from jobs.reproduce.papers import paper_data
from jobs.reproduce.registry import (
    MODES,
    Budget,
    Context,
    ReproduceError,
    figures,
    get_figure,
)
from jobs.reproduce.results import FigureTime, Provenance, Reproduction


def reproduce(paper: str, key: str, mode: str, out_dir: Path, store: Any, settings: Any,
              progress: Any = None, budget: Budget | None = None, job_id: int | None = None
              ) -> tuple[Reproduction, dict[str, Path]]:
    """Figure ``key`` of ``paper`` at ``mode``'s budget (or ``budget``), run by the CLI or
    by the service's job ``job_id``; returns it and the paths written (``figure``,
    ``markdown``, ``json``, ``provenance``: the last, once the others are written)."""
    spec = get_figure(paper, key)
    if mode not in MODES:
        raise ReproduceError(f"unknown mode '{mode}'; choose one of {list(MODES)}")
    with running_marker(out_dir):
        ctx = Context(budget or spec.budgets[mode], store, settings, progress)
        _values, claims = paper_data(paper).of(key)
        clock = Clock()
        # A figure renders scenes as loaded, often one under several grid-cache policies:
        # those share their pre-fills (one per scene and seed).
        from renderers.methods.grid_cache import prefills_shared

        with prefills_shared():
            measured = spec.measure(ctx)
        stated_mode = mode if budget is None else f"{mode} (budget replaced)"
        reproduction = measured.model_copy(update={
            "mode": stated_mode, "work": ctx.work, "claims": [c.model_dump() for c in claims]})
        paths = reproduction.write(out_dir)
        paths["figure"] = spec.draw(reproduction, out_dir / "figure.png")
        provenance = Provenance(job_id=job_id, mode=stated_mode, git_commit=git_commit(),
                                libraries=library_versions(), finished_at=datetime.now(UTC),
                                time=clock.read())
        paths["provenance"] = out_dir / PROVENANCE
        paths["provenance"].write_text(provenance.model_dump_json(indent=1) + "\n")
        return reproduction, paths


class Clock:
    """Wall and CPU seconds since it was made, and the load average then and now."""

    def __init__(self) -> None:
        self.wall = time.perf_counter()
        self.cpu = _cpu_s()
        self.load = os.getloadavg()

    def read(self) -> FigureTime:
        return FigureTime(wall_s=time.perf_counter() - self.wall, cpu_s=_cpu_s() - self.cpu,
                          load_start=list(self.load), load_end=list(os.getloadavg()))


def _cpu_s() -> float:
    """This process's user + system seconds (all its threads), and its waited-for
    children's."""
    times = os.times()
    return times.user + times.system + times.children_user + times.children_system


def default_out_dir(settings: Any, paper: str, key: str) -> Path:
    """Where a figure is written unless ``--out`` says: ``<data>/reproduce/<paper>-<key>``
    (a service's job writes into its ``job-<id>`` folder there)."""
    return settings.reproductions_dir / f"{paper}-{key}"


def latest_times(settings: Any) -> dict[tuple[str, str], Provenance]:
    """Per figure (paper, key), the provenance of its latest reproduction stored in the
    data folder, the CLI's or a job's, among those that recorded what they took (an
    unreadable one is passed over)."""
    latest: dict[tuple[str, str], Provenance] = {}
    for spec in figures():
        folder = default_out_dir(settings, spec.paper, spec.key)
        for path in [folder / PROVENANCE, *folder.glob(f"{JOB_PREFIX}*/{PROVENANCE}")]:
            try:
                provenance = Provenance.model_validate_json(path.read_bytes())
            except (OSError, ValidationError):
                continue
            known = latest.get((spec.paper, spec.key))
            if provenance.time and (known is None or provenance.finished_at > known.finished_at):
                latest[(spec.paper, spec.key)] = provenance
    return latest
