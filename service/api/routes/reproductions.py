"""Reproducing a paper's figure as a job, and the stored reproductions.

``POST /api/v1/reproductions`` queues a registered figure at a mode (a job of kind
``reproduce``, polled at ``/api/v1/jobs/{id}`` like any job), bounded like every job by
the service's limits: a mode's declared time bound (jobs/reproduce/job.py) above
``max_job_seconds`` is refused with 422, so ``full`` is refused by default until an
administrator raises that limit. ``GET /api/v1/reproductions`` lists the stored ones
(table, verdicts, provenance), newest first, and
``GET /api/v1/reproductions/{job_id}`` the one a job stored, with a link to its PNG,
``GET /api/v1/reproductions/{job_id}/figure.png`` (that job's own file only, at most
:data:`~jobs.reproduce.job.REPRODUCTION_BYTES`, 404 saying why when there is none). ``GET
/api/v1/reports/{paper}`` is a paper's report page's data: per catalogued figure its
claims and verdicts, and its latest stored reproduction with its charts
(jobs/views/reproduction_charts.py).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Response, status
from fastapi.responses import JSONResponse

from jobs.execution.queued import QueuedReproduce
from jobs.reproduce.job import (
    FigureUnavailable,
    ReproduceSpec,
    StoredReproduction,
    stored_figure,
    stored_reproduction,
    stored_reproductions,
)
from jobs.reproduce.registry import PAPERS, ReproduceError
from jobs.views.reproduction_charts import reproduction_charts
from service.api.deps import CallerDep, DispatcherDep, QueueDep, RowId, SettingsDep
from service.api.routes.jobs import (
    SUBMISSION_ANSWERS,
    DeviceClass,
    IdempotencyKey,
    _enqueue,
    _unprocessable,
)
from service.api.schemas import JobOut

router = APIRouter(prefix="/api/v1", tags=["reproductions"])


@router.post("/reproductions", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut,
             responses=SUBMISSION_ANSWERS)
def submit_reproduction(spec: ReproduceSpec, response: Response, queue: QueueDep,
                        dispatcher: DispatcherDep, settings: SettingsDep, caller: CallerDep,
                        idempotency_key: IdempotencyKey = None,
                        device_class: DeviceClass = "cpu") -> JobOut | JSONResponse:
    """Queue a figure or table of a paper at a mode (``quick`` or ``full``)."""
    try:
        spec.budget()
    except ReproduceError as err:
        field = "paper" if spec.paper not in PAPERS else "figure"
        raise _unprocessable(field, str(err)) from None
    return _enqueue(QueuedReproduce(spec=spec), queue, dispatcher, response,
                    idempotency_key, device_class, settings, caller)


@router.get("/reproductions", response_model=list[StoredReproduction])
def list_reproductions(settings: SettingsDep,
                       paper: Annotated[str | None, Query(description="one paper's")] = None
                       ) -> list[StoredReproduction]:
    if paper is not None and paper not in PAPERS:
        raise _unprocessable("paper", f"unknown paper '{paper}'; choose one of "
                                      f"{sorted(PAPERS)}")
    return stored_reproductions(settings, paper)


@router.get("/reproductions/{job_id}", response_model=StoredReproduction)
def get_reproduction(job_id: RowId, settings: SettingsDep) -> StoredReproduction:
    stored = stored_reproduction(settings, job_id)
    if stored is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"job {job_id} stored no reproduction (not a reproduce job, "
                            "or not finished)")
    return stored


@router.get("/reproductions/{job_id}/figure.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}},
                       404: {"description": "job stored no figure"}})
def get_reproduction_figure(job_id: RowId, settings: SettingsDep) -> Response:
    """The PNG job ``job_id`` stored: its own file (no path a client names), at most
    4 MiB (``REPRODUCTION_BYTES``); 404 saying why when there is none to serve."""
    stored = stored_reproduction(settings, job_id)
    if stored is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"job {job_id} stored no reproduction (not a reproduce job, "
                            "or not finished)")
    try:
        png = stored_figure(settings, stored)
    except FigureUnavailable as err:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(err)) from None
    return Response(png, media_type="image/png")


@router.get("/reports")
def paper_reports() -> list[dict[str, str]]:
    """The papers with a report page: key, title, reference."""
    return [{"paper": key, "title": paper.title, "reference": paper.reference}
            for key, paper in PAPERS.items()]


def _figure(row: dict[str, Any], stored: StoredReproduction | None) -> dict[str, Any]:
    """A figure of a report: its catalogue row, its latest stored reproduction and charts."""
    if stored is None:
        return {**row, "stored": None, "charts": []}
    reproduction = stored.reproduction.model_dump(mode="json")
    return {**row, "stored": stored.model_dump(mode="json"),
            "charts": reproduction_charts(reproduction)}


@router.get("/reports/{paper}")
def paper_report(paper: str, settings: SettingsDep) -> dict[str, Any]:
    """A paper's figures in the catalogue's order: title, status, the claims with the
    catalogue's verdicts, and the latest stored reproduction (table, verdicts,
    provenance, charts) or None where none was run on this service."""
    from jobs.reproduce.catalogue import listing

    if paper not in PAPERS:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"unknown paper '{paper}'; choose one of {sorted(PAPERS)}")
    latest: dict[str, StoredReproduction] = {}
    for stored in stored_reproductions(settings, paper):   # newest first
        latest.setdefault(stored.reproduction.figure, stored)
    figures = []
    for row in listing():
        if row["paper"] != paper:
            continue
        stored = latest.get(row["figure"])
        figures.append(_figure(row, stored))
    listed = {row["figure"] for row in figures}
    figures += [_figure({"paper": paper, "figure": figure, "title": stored.reproduction.title,
                         "status": "runs", "claims": []}, stored)
                for figure, stored in latest.items() if figure not in listed]
    return {"paper": paper, "title": PAPERS[paper].title,
            "reference": PAPERS[paper].reference, "figures": figures}
