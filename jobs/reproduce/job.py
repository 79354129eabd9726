"""A reproduction run as a service job: its spec (paper, figure, mode), what bounds it,
its run into a folder of the data folder, and the stored reproductions read back.

A figure's budget names its image size, seeds and frames but not what it renders (its
methods, its sweeps), so a job's time is not estimated from measured costs: each mode
declares a bound, :data:`MODE_BOUND_S` (``quick``: minutes on 2 cores, within half an
hour; ``full``: the figure's full budget, hours). The service refuses a job whose bound
exceeds its ``max_job_seconds``, so that by default ``--quick`` is accepted and
``--full`` is refused until an administrator raises that limit.

A job writes ``<data>/reproduce/<paper>-<figure>/job-<id>/``: ``table.json`` (the
:class:`~jobs.reproduce.results.Reproduction`), ``table.md``, ``figure.png`` and
``provenance.json`` (the job, the mode, the commit, the libraries, when it finished,
its wall and CPU seconds and the machine's load: jobs/reproduce/run.py).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from jobs.protocol.provenance import git_commit
from jobs.record.reproduction_folders import JOB_PREFIX, PROVENANCE
from jobs.reproduce.registry import PAPERS, Budget, get_figure
from jobs.reproduce.results import Provenance, Reproduction
from jobs.reproduce.run import default_out_dir, reproduce

#: The seconds each mode is bounded by (declared, see the module doc).
MODE_BOUND_S = {"quick": 1800.0, "full": 12 * 3600.0}
#: Bytes a reproduction's own files may take (PNG, tables, provenance); its points are
#: runs of sweeps, stored and counted as theirs.
REPRODUCTION_BYTES = 4 << 20


class ReproduceSpec(BaseModel):
    """What ``POST /api/v1/reproductions`` submits: a registered figure and a mode."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    paper: str
    figure: str
    mode: Literal["quick", "full"] = "quick"

    def versions(self) -> dict[str, str]:
        """What a stored reproduction depends on beyond its spec: the code's commit (a
        figure's measure may change with any commit)."""
        return {"commit": git_commit()}

    def budget(self) -> Budget:
        """The figure's budget at this mode; ReproduceError naming the choices if the
        paper or figure is not registered."""
        return get_figure(self.paper, self.figure).budgets[self.mode]


def budget_samples(budget: Budget) -> int:
    """Path samples a figure renders at least: one series of its points (its swept
    values, one point without) and one reference (a lower bound: a figure renders
    every series on every scene)."""
    pixels = budget.resolution ** 2
    points = max(1, len(budget.values))
    return pixels * (points * budget.seeds * budget.frames + budget.ref_spp)


def job_dir(settings: Any, spec: ReproduceSpec, job_id: int) -> Path:
    """The folder a job writes: ``<data>/reproduce/<paper>-<figure>/job-<id>``."""
    return default_out_dir(settings, spec.paper, spec.figure) / f"{JOB_PREFIX}{job_id}"


def run_reproduce(spec: ReproduceSpec, store: Any, settings: Any, progress: Any, *,
                  job_id: int) -> Path:
    """Reproduce the figure into its job's folder, with provenance; returns the folder."""
    folder = job_dir(settings, spec, job_id)
    reproduce(spec.paper, spec.figure, spec.mode, folder, store, settings, progress=progress,
              job_id=job_id)
    return folder


def figure_url(job_id: int) -> str:
    """Where the service serves the PNG job ``job_id`` stored."""
    return f"/api/v1/reproductions/{job_id}/figure.png"


class StoredReproduction(BaseModel):
    """A reproduction a job stored: its table and verdicts, and its provenance."""

    job_id: int
    reproduction: Reproduction
    provenance: Provenance
    figure_png: str      # the PNG's path, relative to the data folder
    figure_url: str      # the PNG over REST (GET /api/v1/reproductions/{job_id}/figure.png)


def _stored(settings: Any, provenance: Path) -> StoredReproduction:
    folder = provenance.parent
    job_id = int(folder.name.removeprefix(JOB_PREFIX))
    return StoredReproduction(
        job_id=job_id,
        reproduction=Reproduction.model_validate_json((folder / "table.json").read_text()),
        provenance=Provenance.model_validate_json(provenance.read_bytes()),
        figure_png=str((folder / "figure.png").relative_to(settings.data_dir)),
        figure_url=figure_url(job_id))


class FigureUnavailable(Exception):
    """A stored reproduction's PNG that is not served: gone, not a plain file (a link is
    not followed), not a PNG, or larger than :data:`REPRODUCTION_BYTES`."""


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def stored_figure(settings: Any, stored: StoredReproduction) -> bytes:
    """The bytes of the PNG ``stored`` names (its job's own file); FigureUnavailable
    saying why if it cannot be served."""
    path = Path(settings.data_dir) / stored.figure_png
    name = f"the figure of job {stored.job_id}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except FileNotFoundError:
        raise FigureUnavailable(f"{name} is gone (removed, or never drawn)") from None
    except OSError as err:
        raise FigureUnavailable(f"{name} cannot be read ({err.strerror})") from None
    with os.fdopen(fd, "rb") as file:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise FigureUnavailable(f"{name} is not a file")
        png = file.read(REPRODUCTION_BYTES + 1)
    if len(png) > REPRODUCTION_BYTES:
        raise FigureUnavailable(f"{name} is larger than the {REPRODUCTION_BYTES >> 20} MiB "
                                "a reproduction's files may take: not served")
    if not png.startswith(PNG_SIGNATURE):
        raise FigureUnavailable(f"{name} is not a PNG")
    return png


def stored_reproductions(settings: Any, paper: str | None = None) -> list[StoredReproduction]:
    """Every stored reproduction (of ``paper``, if given), newest job first; a folder
    without its provenance (a job that did not finish) is skipped."""
    root = settings.reproductions_dir
    keys = [paper] if paper is not None else list(PAPERS)
    found = [_stored(settings, provenance) for key in keys
             for provenance in root.glob(f"{key}-*/{JOB_PREFIX}*/{PROVENANCE}")]
    return sorted(found, key=lambda stored: -stored.job_id)


def stored_reproduction(settings: Any, job_id: int) -> StoredReproduction | None:
    """The reproduction job ``job_id`` stored, None if it stored none."""
    root = settings.reproductions_dir
    found = [_stored(settings, provenance)
             for provenance in root.glob(f"*-*/{JOB_PREFIX}{job_id}/{PROVENANCE}")]
    return found[0] if found else None
