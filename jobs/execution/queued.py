"""A queued job, typed: one discriminated union over what the queue runs.

The queue stores a job as a row: its ``kind`` and its spec as JSON (which is what
is hashed into its keys, and never changes shape). Everything above the row works
on a :data:`QueuedJob` instead, made once where a job enters — the REST routes and
the CLI build it from the request or the options, a runner from the row it claimed
(:func:`job_of`) — and passed down:

* :class:`QueuedRender`: a render (its :class:`~jobs.protocol.job.RenderJob`, the
  spec with the method's typed parameters);
* :class:`QueuedSweep`: a sweep (its :class:`~jobs.protocol.spec.SweepSpec`), run as
  its stages (jobs/execution/graph.py) and its own last step;
* :class:`QueuedStage`: one stage of a sweep (the sweep's spec and the stage's task);
* :class:`QueuedReproduce`: one registered figure of a paper at a budget
  (jobs/reproduce), its Reproduction written under the data folder with provenance.

Each variant owns what differs between the kinds: its dedupe key, the methods and
scene its time is estimated from, its work (jobs/execution/work.py), its stages and
its run. Nothing outside this module branches on the kind.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, InstanceOf, TypeAdapter, model_validator

from jobs.execution.graph import Stage, sweep_stages
from jobs.execution.queue import JobQueue, spec_key
from jobs.execution.timecost import TimeEstimate, estimate_seconds
from jobs.execution.work import WorkEstimate, reference_stored, render_work, stage_work, sweep_work
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import SweepSpec
from jobs.record.config import Settings
from jobs.record.store import Store
from jobs.reproduce.job import (
    MODE_BOUND_S,
    REPRODUCTION_BYTES,
    ReproduceSpec,
    budget_samples,
    run_reproduce,
)

#: report(stage, done, total): a running job's progress.
Progress = Any


class _Queued(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    def time(self, work: WorkEstimate, store: Store, device_class: str) -> TimeEstimate:
        """The estimated seconds of ``work`` (this job's) on ``device_class``: from the
        measured costs of its methods on its scene (jobs/execution/timecost.py)."""
        return estimate_seconds(work, self.methods, self.scene, store, device_class)


class QueuedRender(_Queued):
    """A render job; from a row: its spec parsed once (:meth:`RenderJob.parse`)."""

    kind: Literal["render"] = "render"
    job: InstanceOf[RenderJob]

    @model_validator(mode="before")
    @classmethod
    def _from_row(cls, data: Any) -> Any:
        if isinstance(data, dict) and "stored" in data:
            return {"kind": data["kind"], "job": RenderJob.parse(data["stored"])}
        return data

    def stored(self) -> dict[str, Any]:
        """The spec JSON the row stores."""
        return self.job.spec.model_dump(mode="json")

    def key(self, device_class: str) -> str:
        return spec_key(self.kind, self.job.spec, device_class)

    @property
    def scene(self) -> str:
        return self.job.spec.scene

    @property
    def methods(self) -> list[str]:
        return [self.job.method]

    def stages(self) -> list[Stage]:
        return []

    def work(self, store: Store | None = None) -> WorkEstimate:
        """What submitting it costs; the reference counted unless ``store`` holds it."""
        spec = self.job.spec
        stored = store is not None and reference_stored(
            store, spec.scene, spec.resolution, spec.reference, self.job.max_depth)
        return render_work(spec, stored, self.job.params)

    def attempt_work(self) -> WorkEstimate:
        """What one attempt runs (the reference counted)."""
        return render_work(self.job.spec, params=self.job.params)

    def run(self, store: Store, settings: Settings, progress: Progress, *, job_id: int,
            reuse: bool = False) -> dict[str, Any]:
        """Render through the one executor, stored under the idempotency key
        ``job-<id>`` (an earlier attempt that stored it, then died, is the result);
        returns the run id and the work counters (reference rendered now, run reused)."""
        from jobs.protocol.executor import execute

        key = f"job-{job_id}"
        stored = store.find_run_by_idempotency_key(key)
        if stored is not None:
            return {"run_id": stored.id}
        summary = execute(self.job, store, settings, progress=progress, idempotency_key=key,
                          reuse=reuse)
        return {"run_id": summary.run_id,
                "work": {"reference_rendered": int(summary.reference.get("rendered_now", False)),
                         "run_reused": int(summary.reused)}}


class _SpecQueued(_Queued):
    """A job whose stored row is its ``spec`` (a sweep, a reproduction): parsed back from
    the row, stored and keyed by it."""

    @model_validator(mode="before")
    @classmethod
    def _from_row(cls, data: Any) -> Any:
        if isinstance(data, dict) and "stored" in data:
            return {"kind": data["kind"], "spec": data["stored"]}
        return data

    def stored(self) -> dict[str, Any]:
        return self.spec.model_dump(mode="json")

    def key(self, device_class: str) -> str:
        return spec_key(self.kind, self.spec, device_class)


class QueuedSweep(_SpecQueued):
    """A sweep job: its stages run as jobs of their own, then its last step here."""

    kind: Literal["sweep"] = "sweep"
    spec: SweepSpec

    @property
    def scene(self) -> str:
        return self.spec.scene

    @property
    def methods(self) -> list[str]:
        return list(self.spec.methods)

    def stages(self) -> list[Stage]:
        return sweep_stages(self.spec)

    def work(self, store: Store | None = None) -> WorkEstimate:
        """What submitting it costs: every stage and its own step (references counted)."""
        return sweep_work(self.spec, self.stages())

    def attempt_work(self) -> WorkEstimate:
        """What one attempt runs: its own step (its stages are jobs of their own)."""
        return stage_work(self.spec, {"stage": "sweep"})

    def run(self, store: Store, settings: Settings, progress: Progress, *, job_id: int,
            reuse: bool = False) -> dict[str, Any]:
        """The last step, over the stored results of its stages; returns the sweep id."""
        from jobs.sweeps.sweep import run_sweep

        result = run_sweep(self.spec, store, settings, progress=progress,
                           stage_work=JobQueue(store).stage_work(job_id))
        return {"sweep_id": result.sweep_id}


class QueuedStage(_Queued):
    """One stage of a sweep job (jobs.execution.graph.Stage), a job of its own."""

    kind: Literal["stage"] = "stage"
    sweep: SweepSpec
    name: str
    task: dict[str, Any]

    @model_validator(mode="before")
    @classmethod
    def _from_row(cls, data: Any) -> Any:
        if isinstance(data, dict) and "stored" in data:
            return {"kind": data["kind"], **data["stored"]}
        return data

    @property
    def scene(self) -> str:
        return self.sweep.scene

    @property
    def methods(self) -> list[str]:
        return list(self.sweep.methods)

    def stages(self) -> list[Stage]:
        return []

    def work(self, store: Store | None = None) -> WorkEstimate:
        return stage_work(self.sweep, self.task)

    def attempt_work(self) -> WorkEstimate:
        return self.work()

    def run(self, store: Store, settings: Settings, progress: Progress, *, job_id: int,
            reuse: bool = False) -> dict[str, Any]:
        """Run the stage; returns its work counters."""
        from jobs.sweeps.sweep import run_stage

        return {"work": run_stage(self.sweep, self.task, store, settings, progress=progress)}


class QueuedReproduce(_SpecQueued):
    """A registered figure of a paper at the budget of ``mode`` (jobs/reproduce/job.py)."""

    kind: Literal["reproduce"] = "reproduce"
    spec: ReproduceSpec

    @property
    def scene(self) -> str:
        return ""

    @property
    def methods(self) -> list[str]:
        return []

    def stages(self) -> list[Stage]:
        return []

    def work(self, store: Store | None = None) -> WorkEstimate:
        """At least the path samples of its budget (jobs.reproduce.job.budget_samples)."""
        estimate = WorkEstimate()
        estimate.add("figure", budget_samples(self.spec.budget()), REPRODUCTION_BYTES)
        return estimate

    def attempt_work(self) -> WorkEstimate:
        return self.work()

    def time(self, work: WorkEstimate, store: Store, device_class: str) -> TimeEstimate:
        """The mode's declared bound (a figure's budget does not name what it renders)."""
        bound = MODE_BOUND_S[self.spec.mode]
        return TimeEstimate(seconds=bound, parts={f"{self.spec.mode} mode": bound},
                            sources={f"{self.spec.mode} mode": "the mode's declared bound"})

    def run(self, store: Store, settings: Settings, progress: Progress, *, job_id: int,
            reuse: bool = False) -> dict[str, Any]:
        """Measure and draw the figure into its job's folder, with provenance."""
        run_reproduce(self.spec, store, settings, progress, job_id=job_id)
        return {}


#: What the queue runs, discriminated by the row's ``kind``.
QueuedJob = Annotated[QueuedRender | QueuedSweep | QueuedStage | QueuedReproduce,
                      Field(discriminator="kind")]
_QUEUED_JOB: TypeAdapter[QueuedRender | QueuedSweep | QueuedStage | QueuedReproduce] = \
    TypeAdapter(QueuedJob)


def job_of(row: Any) -> QueuedRender | QueuedSweep | QueuedStage | QueuedReproduce:
    """The typed job of a queue row (its ``kind`` and stored spec), parsed once."""
    return _QUEUED_JOB.validate_python({"kind": row.kind, "stored": row.spec})
