"""Submitting, polling and canceling jobs and sweeps."""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Literal

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response, status
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from jobs.models import FINAL_JOB_STATES
from jobs.queue import spec_key
from jobs.spec import RenderSpec, SweepSpec
from renderers.methods import MethodError, format_validation_error, get_method
from renderers.scenes import builtin_names, is_scene_file
from service.api.deps import DispatcherDep, QueueDep, RowId, SettingsDep, WriteAccess
from service.api.schemas import JobOut

router = APIRouter(prefix="/api/v1", tags=["jobs"])

#: Seconds between the reads of a long-polled job: short at first (a job that is about
#: to finish answers quickly), growing to the longest while it keeps running.
LONG_POLL_INTERVAL_S = 0.1
LONG_POLL_MAX_INTERVAL_S = 1.0

IdempotencyKey = Annotated[str | None, Header(max_length=200,
                                              description="return the job of an earlier "
                                                          "submission with this key")]
DeviceClass = Annotated[Literal["cpu", "gpu"], Query(description="worker class to run on")]


def _unprocessable(field: str, message: str) -> HTTPException:
    return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                         [{"loc": ["body", field], "msg": message, "type": "value_error"}])


def _check_scene(scene: str) -> None:
    if scene not in builtin_names() and not is_scene_file(scene):
        raise _unprocessable("scene", f"unknown scene '{scene}'; built-ins: "
                                      f"{', '.join(builtin_names())}, or a Mitsuba XML path "
                                      "on the service's machine")


def _check_params(method: str, params: dict) -> None:
    """``params`` as ``method``'s parameter model takes them, strictly: in a request
    body a string or a boolean is not a number (the CLI's --param values are JSON too)."""
    try:
        get_method(method).params.model_validate(params, strict=True)
    except MethodError as err:
        raise _unprocessable("params", str(err)) from None
    except ValidationError as err:
        raise _unprocessable("params", f"invalid {method} parameters: "
                                       f"{format_validation_error(err)}") from None


def _check_render(spec: RenderSpec) -> None:
    _check_scene(spec.scene)
    _check_params(spec.method, spec.params)


def _enqueue(kind: str, spec: RenderSpec | SweepSpec, queue, dispatcher, response: Response,
             idempotency_key: str | None, device_class: str) -> JobOut:
    reason = dispatcher.unavailable(device_class) if dispatcher is not None else None
    if reason:
        raise HTTPException(status.HTTP_409_CONFLICT, reason)
    job, created = queue.submit(kind, spec.model_dump(mode="json"),
                                spec_key(kind, spec, device_class),
                                idempotency_key=idempotency_key, device_class=device_class)
    if created and dispatcher is not None:
        dispatcher.submit(job)
    response.headers["Location"] = f"/api/v1/jobs/{job.id}"
    return JobOut.of(job)


@router.post("/jobs", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut,
             dependencies=[WriteAccess])
def submit_job(spec: RenderSpec, response: Response, queue: QueueDep,
               dispatcher: DispatcherDep, idempotency_key: IdempotencyKey = None,
               device_class: DeviceClass = "cpu") -> JobOut:
    """Queue a render job (K seeds of a method on a scene, against its reference)."""
    _check_render(spec)
    return _enqueue("render", spec, queue, dispatcher, response,
                    idempotency_key, device_class)


@router.post("/sweeps", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut,
             dependencies=[WriteAccess])
def submit_sweep(spec: SweepSpec, response: Response, queue: QueueDep,
                 dispatcher: DispatcherDep, idempotency_key: IdempotencyKey = None,
                 device_class: DeviceClass = "cpu") -> JobOut:
    """Queue a sweep (adaptive equal-bias over eps, or over N_c); poll it as a job."""
    _check_scene(spec.scene)
    for method in spec.methods:
        _check_params(method, spec.params)
    return _enqueue("sweep", spec, queue, dispatcher, response,
                    idempotency_key, device_class)


@router.get("/jobs", response_model=list[JobOut])
def list_jobs(queue: QueueDep,
              status_: Annotated[Literal["queued", "running", "succeeded", "failed",
                                         "canceled"] | None, Query(alias="status")] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[JobOut]:
    return [JobOut.of(job) for job in queue.list(status_, limit=limit)]


@router.get("/jobs/{job_id}", response_model=JobOut,
            description="A job's status and progress; a sweep lists its stages (the task "
                        "graph: reference, caches, points), each a job of its own. With "
                        "wait_s, 429 while the service already holds its most long polls.")
async def get_job(job_id: RowId, request: Request, queue: QueueDep, settings: SettingsDep,
                  wait_s: Annotated[float, Query(
                      ge=0, le=60, description="long poll: answer when the job is final or "
                                               "after this many seconds (at most the "
                                               "service's long_poll_max_s), whichever is "
                                               "first")] = 0) -> JobOut:
    # Async, with each database read in a worker thread: a waiting poll holds no thread,
    # so polls cannot starve the thread pool that the other endpoints run on.
    deadline = time.monotonic() + min(wait_s, settings.long_poll_max_s)
    job = await run_in_threadpool(queue.get, job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no job {job_id}")
    if job.status not in FINAL_JOB_STATES and time.monotonic() < deadline:
        job = await _wait_until_final(request, queue, job, deadline,
                                      settings.long_poll_max_waiters)
    stages = await run_in_threadpool(queue.children, job_id) if job.kind == "sweep" else None
    return JobOut.of(job, stages)


async def _wait_until_final(request: Request, queue, job, deadline: float, max_waiters: int):
    """``job`` re-read until it is final, the deadline passes or the client leaves.

    Re-read the row, not the HTTP round trip: a waiting client costs one query per
    interval instead of one request."""
    state = request.app.state
    waiting = getattr(state, "long_poll_waiters", 0)
    if waiting >= max_waiters:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"the service already holds {waiting} long polls; poll again "
                            "shortly, or without wait_s", headers={"Retry-After": "2"})
    state.long_poll_waiters = waiting + 1     # one event loop: no lock needed
    try:
        interval = LONG_POLL_INTERVAL_S
        while job.status not in FINAL_JOB_STATES and time.monotonic() < deadline:
            await asyncio.sleep(min(interval, max(0.0, deadline - time.monotonic())))
            if await request.is_disconnected():
                break
            job = await run_in_threadpool(queue.get, job.id)
            interval = min(1.5 * interval, LONG_POLL_MAX_INTERVAL_S)
        return job
    finally:
        state.long_poll_waiters -= 1


@router.post("/jobs/{job_id}/cancel", response_model=JobOut, dependencies=[WriteAccess])
def cancel_job(job_id: RowId, queue: QueueDep) -> JobOut:
    """Cancel a queued job now; a running job is stopped by its runner."""
    job = queue.cancel(job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no job {job_id}")
    return JobOut.of(job)
