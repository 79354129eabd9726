"""Submitting, polling and canceling jobs and sweeps.

A job belongs to the API key that submitted it: only that key, or an admin key,
may cancel it; a key's Idempotency-Keys are its own; a key holds at most
``max_jobs_per_key`` unfinished jobs (429 beyond). An identical spec already live
or done is answered with that job, whoever submitted it (the work is done once),
and a job found that way which nothing is running is dispatched again; if it is
stalled (the service cannot write its database), the answer is 503 with the job and
the reason instead of a 202. Room on disk (a key's quota, the free-space floor) is
checked before a new job is queued, not for one answered by an existing job (which
writes nothing more): service/api/quota.py.
"""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from jobs.execution.queue import IdempotencyKeyReused, TooManyJobs
from jobs.execution.queued import QueuedRender, QueuedSweep
from jobs.execution.work import WorkEstimate, data_bytes
from jobs.protocol.job import RenderJob
from jobs.protocol.scene_store import builtin_features, named_scenes, rest_scene
from jobs.protocol.spec import RenderSpec, SweepSpec
from jobs.record.config import Settings
from jobs.record.models import FINAL_JOB_STATES, ApiKey
from renderers.backend import BackendError
from renderers.methods import (
    MethodError,
    NotApplicable,
    check_applies,
    parse_params,
)
from renderers.scenes.animated import animated_names
from renderers.scenes.vetting import SceneRefused
from service.api.deps import CallerDep, DispatcherDep, QueueDep, RowId, SettingsDep
from service.api.failures import RETRY_AFTER_S
from service.api.quota import check_room
from service.api.schemas import JobOut
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1", tags=["jobs"])

#: Seconds between the reads of a long-polled job: short at first (a job that is about
#: to finish answers quickly), growing to the longest while it keeps running.
LONG_POLL_INTERVAL_S = 0.1
LONG_POLL_MAX_INTERVAL_S = 1.0

IdempotencyKey = Annotated[str | None, Header(max_length=200,
                                              description="return the job of an earlier "
                                                          "submission with this key")]
DeviceClass = Annotated[Literal["cpu", "gpu"], Query(description="worker class to run on")]


def _unprocessable(field: str, message: str) -> RequestValidationError:
    return unprocessable(message, ("body", field))


def _check_scene(scene: str, settings: Settings) -> str:
    """The scene as the job will name it: a built-in, or the id of a stored, vetted
    copy (jobs.protocol.scene_store). A scene that does not exist and one that may not be used
    get the same answer."""
    try:
        return rest_scene(scene, settings)
    except SceneRefused as err:
        raise _unprocessable("scene", str(err)) from None


def _check_render(spec: RenderSpec, settings: Settings) -> QueuedRender:
    """The request's job, parsed here once (strictly, as everywhere: a string or a
    boolean is not a number), with the scene checked."""
    try:
        job = RenderJob.parse(spec)
    except MethodError as err:
        raise _unprocessable("params", str(err)) from None
    job = job.with_spec(scene=_check_scene(spec.scene, settings))
    if spec.animation is not None and spec.scene in animated_names():
        raise _unprocessable("animation", f"scene '{spec.scene}' is animated already: give "
                                          "an animation only with a static scene")
    _check_applies(job)
    return QueuedRender(job=job)


def _check_sweep(spec: SweepSpec, settings: Settings) -> QueuedSweep:
    """The request's sweep, with its parameters as each of its methods takes them and
    the scene checked."""
    for method in spec.methods:
        try:
            parse_params(method, spec.params)
        except MethodError as err:
            raise _unprocessable("params", str(err)) from None
    scene = _check_scene(spec.scene, settings)
    return QueuedSweep(spec=spec.model_copy(update={"scene": scene}))


def _check_applies(job: RenderJob) -> None:
    """Refuse (422) a method that does not apply to a built-in scene, from the scene's
    features, before the job is queued. A stored scene is not loaded here (an upload
    may be large; its render process loads it) and neither is anything where no scene
    can be loaded: the render process refuses those first thing, before the reference."""
    if job.spec.scene not in named_scenes():
        return
    try:
        check_applies(job.method, builtin_features(job.spec.scene))
    except NotApplicable as err:
        raise _unprocessable("method", str(err)) from None
    except BackendError:
        return


def _check_work(job: QueuedRender | QueuedSweep, store, settings,
                device_class: str) -> WorkEstimate:
    """Refuse what is too big before it is queued: too many stage jobs, samples or
    estimated seconds for this service's limits (422). Returns the job's estimate."""
    kind = job.kind
    stages = len(job.stages())
    if stages > settings.max_sweep_stages:
        raise _unprocessable("seeds", (
            f"this {kind} would make {stages} stage jobs (one per seed and method, or "
            f"per N_c value, plus the reference); this service allows "
            f"{settings.max_sweep_stages} (max_sweep_stages)"))
    estimate = job.work(store)
    if estimate.samples > settings.max_job_work:
        parts = ", ".join(f"{name} {samples:.3g}" for name, samples in estimate.parts.items())
        raise unprocessable(
            f"this {kind} job is estimated at {estimate.samples:.3g} path samples "
            f"({parts}); this service allows {settings.max_job_work:.3g} per job "
            "(max_job_work): lower the resolution, spp, frames or seeds")
    if settings.max_job_seconds is not None:
        time = job.time(estimate, store, device_class)
        if time.seconds > settings.max_job_seconds:
            raise unprocessable(
                f"this {kind} job is estimated to take {time.seconds:.0f} s on this "
                f"service ({time.describe()}; from {_sources(time.sources)}); this service "
                f"allows {settings.max_job_seconds:.0f} s per job (max_job_seconds): lower "
                "the resolution, spp, frames, seeds or the number of sweep points",
                ctx={"estimated_s": round(time.seconds, 1),
                     "parts_s": {part: round(seconds, 1) for part, seconds in time.parts.items()},
                     "limit_s": settings.max_job_seconds})
    return estimate


def _check_room(estimate: WorkEstimate, kind: str, store, settings, key_id: int) -> None:
    """Refuse a new job whose files the disk has no room for: more than the data
    folder's cap, or its free-space floor or the key's quota allow (507,
    service/api/quota.py)."""
    if settings.max_data_bytes is not None:
        used = data_bytes(store, settings)
        if used + estimate.artifact_bytes > settings.max_data_bytes:
            raise HTTPException(status.HTTP_507_INSUFFICIENT_STORAGE, (
                f"the data folder holds {used / 1e6:.1f} MB and this {kind} may write "
                f"{estimate.artifact_bytes / 1e6:.1f} MB more, past this service's limit "
                f"of {settings.max_data_bytes / 1e6:.1f} MB (max_data_bytes); free space "
                "with `nirc-bench gc --apply`"))
    check_room(store, settings, key_id, estimate.artifact_bytes, f"{kind} job")


def _sources(sources: dict[str, str]) -> str:
    """Where the estimate's costs came from, each source once."""
    return "; ".join(dict.fromkeys(sources.values()))


def _enqueue(parsed: QueuedRender | QueuedSweep, queue, dispatcher, response: Response,
             idempotency_key: str | None, device_class: str, settings,
             caller: ApiKey) -> JobOut | JSONResponse:
    reason = dispatcher.unavailable(device_class) if dispatcher is not None else None
    if reason:
        raise HTTPException(status.HTTP_409_CONFLICT, reason)
    estimate = _check_work(parsed, queue.store, settings, device_class)
    try:
        # Room is asked of a new job only: an identical one (or an Idempotency-Key's)
        # answers without writing anything more.
        job, created = queue.submit(parsed.kind, parsed.stored(), parsed.key(device_class),
                                    idempotency_key=idempotency_key, device_class=device_class,
                                    owner_key_id=caller.id,
                                    max_unfinished=settings.max_jobs_per_key,
                                    admit=lambda: _check_room(estimate, parsed.kind,
                                                              queue.store, settings, caller.id))
    except IdempotencyKeyReused as err:
        raise unprocessable(str(err), ("header", "Idempotency-Key")) from None
    except TooManyJobs as err:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, str(err),
                            headers={"Retry-After": "60"}) from None
    if dispatcher is not None:
        if created:
            dispatcher.submit(job)
        else:   # a duplicate: never answer with a job that nothing will run
            dispatcher.recover([job])
    location = f"/api/v1/jobs/{job.id}"
    answer = JobOut.of(job, stalled=queue.stalled(job, settings.job_lease_s),
                       data_dir=settings.data_dir)
    if answer.stalled is not None:
        # The job exists and was dispatched again, but cannot run before the service
        # can write its database: not an acceptance, a retry later.
        return JSONResponse(
            {"detail": f"job {job.id} of this spec is stalled ({answer.stalled}); it was "
                       "dispatched again and runs once the service can write its database: "
                       f"poll {location}", "job": answer.model_dump(mode="json")},
            status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
            headers={"Location": location, "Retry-After": str(RETRY_AFTER_S)})
    response.headers["Location"] = location
    return answer


#: Answers of a submission besides 202 that the OpenAPI document lists.
SUBMISSION_ANSWERS: dict[int | str, dict[str, Any]] = {
    503: {"description": "the spec's job exists but is stalled (the service cannot write "
                         "its database): `detail` says why, `job` is the job, `Location` "
                         "its URL; send again or poll after Retry-After"},
    507: {"description": "no room: the data folder's cap or free-space floor, or the API "
                         "key's quota (`limit` names the setting, with the numbers)"}}


@router.post("/jobs", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut,
             responses=SUBMISSION_ANSWERS)
def submit_job(spec: RenderSpec, response: Response, queue: QueueDep,
               dispatcher: DispatcherDep, settings: SettingsDep, caller: CallerDep,
               idempotency_key: IdempotencyKey = None,
               device_class: DeviceClass = "cpu") -> JobOut | JSONResponse:
    """Queue a render job (K seeds of a method on a scene, against its reference)."""
    return _enqueue(_check_render(spec, settings), queue, dispatcher, response,
                    idempotency_key, device_class, settings, caller)


@router.post("/sweeps", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut,
             responses=SUBMISSION_ANSWERS)
def submit_sweep(spec: SweepSpec, response: Response, queue: QueueDep,
                 dispatcher: DispatcherDep, settings: SettingsDep, caller: CallerDep,
                 idempotency_key: IdempotencyKey = None,
                 device_class: DeviceClass = "cpu") -> JobOut | JSONResponse:
    """Queue a sweep (adaptive equal-bias over eps, or over N_c); poll it as a job."""
    return _enqueue(_check_sweep(spec, settings), queue, dispatcher, response,
                    idempotency_key, device_class, settings, caller)


@router.get("/jobs", response_model=list[JobOut])
def list_jobs(queue: QueueDep, settings: SettingsDep,
              status_: Annotated[Literal["queued", "running", "succeeded", "failed",
                                         "canceled"] | None, Query(alias="status")] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[JobOut]:
    return [JobOut.of(job, stalled=queue.stalled(job, settings.job_lease_s),
                      data_dir=settings.data_dir)
            for job in queue.list(status_, limit=limit)]


@router.get("/jobs/{job_id}", response_model=JobOut,
            description="A job's status and progress; a sweep lists its stages (the task "
                        "graph: reference, caches, points), each a job of its own. With "
                        "wait_s, 429 while the service already holds its most long polls.")
async def get_job(job_id: RowId, request: Request, queue: QueueDep, settings: SettingsDep,
                  wait_s: Annotated[float, Query(
                      ge=0, le=60, allow_inf_nan=False,
                      description="long poll: answer when the job is final or after "
                                  "this many seconds (at most the service's "
                                  "long_poll_max_s), whichever is first")] = 0) -> JobOut:
    # Async, with each database read in a worker thread: a waiting poll holds no thread,
    # so polls cannot starve the thread pool that the other endpoints run on.
    deadline = time.monotonic() + min(wait_s, settings.long_poll_max_s)
    job = await run_in_threadpool(queue.get, job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no job {job_id}")
    if job.status not in FINAL_JOB_STATES and time.monotonic() < deadline:
        job = await _wait_until_final(request, queue, job, deadline,
                                      settings.long_poll_max_waiters)
    return JobOut.of(job, await run_in_threadpool(queue.children, job_id),
                     stalled=queue.stalled(job, settings.job_lease_s),
                     data_dir=settings.data_dir)


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


@router.post("/jobs/{job_id}/cancel", response_model=JobOut)
def cancel_job(job_id: RowId, queue: QueueDep, caller: CallerDep,
               settings: SettingsDep) -> JobOut:
    """Cancel a queued job now (the answer says 'canceled'); a running job is stopped by
    its runner (the answer, and every read until it has stopped, says 'canceling'). Only
    the key that submitted the job, or an admin key, may cancel it (403 otherwise)."""
    job = queue.get(job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no job {job_id}")
    if job.owner_key_id != caller.id and not caller.admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, (
            f"job {job_id} was submitted by another API key; only that key or an admin key "
            "(`nirc-bench apikey create --admin`) may cancel it"))
    return JobOut.of(queue.cancel(job_id), data_dir=settings.data_dir)
