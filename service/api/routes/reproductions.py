"""Reproducing a paper's figure as a job, and the stored reproductions.

``POST /api/v1/reproductions`` queues a registered figure at a mode (a job of kind
``reproduce``, polled at ``/api/v1/jobs/{id}`` like any job), bounded like every job by
the service's limits: a mode's declared time bound (jobs/reproduce/job.py) above
``max_job_seconds`` is refused with 422, so ``full`` is refused by default until an
administrator raises that limit. ``GET /api/v1/reproductions`` lists the stored ones
(table, verdicts, provenance), newest first, and
``GET /api/v1/reproductions/{job_id}`` the one a job stored.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response, status
from fastapi.responses import JSONResponse

from jobs.execution.queued import QueuedReproduce
from jobs.reproduce.job import (
    ReproduceSpec,
    StoredReproduction,
    stored_reproduction,
    stored_reproductions,
)
from jobs.reproduce.registry import PAPERS, ReproduceError
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
