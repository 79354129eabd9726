"""Jobs run in an isolated child process: results stored once, crashes retried, bad
input failed for good, timeouts and cancels kill the child, the parent survives, and
what the render libraries print never reaches the status channel."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time

import psutil
import pytest

from jobs.execution import runner
from jobs.execution.queue import JobQueue
from jobs.execution.runner import Follow, _Child, run_job
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store

SPEC = RenderSpec(scene="cornell-box", resolution=8, spp=1, frames=2, seeds=2,
                  reference=ReferenceSpec(spp=64, spp_per_pass=8))

#: Mitsuba warns on its log (the process's stdout) that a sphere's to_world should not
#: scale non-uniformly: every job on this scene makes the render process print.
WARNING_SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="sphere">
        <transform name="to_world"><scale x="1" y="2" z="1"/></transform>
    </shape>
</scene>
"""


def _submit(queue: JobQueue, spec: dict, key: str, **kwargs):
    job, _ = queue.submit("render", spec, key, **kwargs)
    return job


def test_a_job_runs_in_a_child_and_stores_its_run(store, settings):
    queue = JobQueue(store)
    job = _submit(queue, SPEC.model_dump(mode="json"), "ok")
    assert run_job(job.id, settings, worker="test") == "succeeded"
    done = queue.get(job.id)
    assert done.attempts == 1 and done.run_id is not None
    run = store.get_run(done.run_id)
    assert run.idempotency_key == f"job-{job.id}" and run.seeds == 2
    assert done.progress["done"] == done.progress["total"]


def test_its_caller_follows_the_progress_and_may_take_a_stored_run(store, settings,
                                                                     monkeypatch):
    """The render process's progress reaches the caller stage by stage, each seed from its
    start; with reuse, a second job of the spec is answered with the first one's run."""
    monkeypatch.setenv("NIRC_BENCH_GIT_COMMIT", "0123456789abcdef")    # clean: reusable
    queue = JobQueue(store)
    reports: list[tuple[str, int, int]] = []
    first = _submit(queue, SPEC.model_dump(mode="json"), "first")
    assert run_job(first.id, settings, worker="test",
                   follow=Follow(progress=lambda *report: reports.append(report))) == "succeeded"
    seeds = [report for report in reports if report[0].startswith("seed")]
    assert seeds[0] == ("seed 1/2", 0, 2) and seeds[-1] == ("seed 2/2", 2, 2)
    assert ("seed 2/2", 0, 2) in seeds and reports[0][0] == "reference"
    assert queue.get(first.id).work == {"reference_rendered": 1, "run_reused": 0}
    second = _submit(queue, SPEC.model_dump(mode="json"), "second")
    assert run_job(second.id, settings, worker="test", follow=Follow(reuse=True)) == "succeeded"
    done = queue.get(second.id)
    assert done.run_id == queue.get(first.id).run_id
    assert done.work == {"reference_rendered": 0, "run_reused": 1}


def test_a_runner_thread_keeps_one_store_for_the_jobs_it_runs(settings, tmp_path,
                                                               monkeypatch):
    """One store (engine, pooled connections) per thread and database, not one per job;
    another database gets its own, and so does a process forked from the runner."""
    opened = []

    def counted(of: Settings):
        opened.append(open_store(of))
        return opened[-1]

    monkeypatch.setattr(runner, "open_store", counted)
    missing = 10**6     # a job id with no row: run_job claims nothing and returns at once
    other = Settings(data_dir=tmp_path / "other")
    for of in (settings, settings, other, settings):
        assert run_job(missing, of, worker="test") == "missing"
    assert len(opened) == 3
    pid = os.fork()
    if pid == 0:    # the forked copy of this thread's store is not the child's
        os._exit(0 if run_job(missing, settings, worker="fork") == "missing"
                 and len(opened) == 4 else 1)
    assert os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0
    assert run_job(missing, settings, worker="test") == "missing" and len(opened) == 3


def test_bad_input_fails_once_with_the_message(store, settings):
    queue = JobQueue(store)
    job = _submit(queue, {**SPEC.model_dump(mode="json"), "scene": "no-such-scene"}, "bad")
    assert run_job(job.id, settings, worker="test") == "failed"
    failed = queue.get(job.id)
    assert failed.attempts == 1 and "no-such-scene" in failed.error


def _is_render_process(process: psutil.Process) -> bool:
    try:
        return "jobs.execution.runner" in process.cmdline()
    except psutil.Error:     # exited meanwhile
        return False


def test_a_killed_child_is_retried_and_the_job_completes_once(store, settings):
    """Kill the render process mid-job (as an LLVM abort would): the attempt fails, the
    next attempt completes, and exactly one run is stored."""
    queue = JobQueue(store)
    spec = SPEC.model_copy(update={"frames": 200, "resolution": 16})
    job = _submit(queue, spec.model_dump(mode="json"), "crash")
    killed = threading.Event()

    def kill_first_child() -> None:
        me = psutil.Process()
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            # Only the render process: other children (a browser from another test)
            # may be alive too.
            children = [p for p in me.children(recursive=True) if _is_render_process(p)]
            if children and queue.get(job.id).progress.get("stage", "").startswith("seed"):
                children[0].kill()
                killed.set()
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_first_child)
    killer.start()
    status = run_job(job.id, settings, worker="test")
    killer.join()
    assert killed.is_set() and status == "succeeded"
    done = queue.get(job.id)
    assert done.attempts == 2
    assert len([r for r in store.list_runs() if r.idempotency_key == f"job-{job.id}"]) == 1


def test_a_timeout_kills_the_attempt_and_gives_up_after_max_attempts(store, settings):
    queue = JobQueue(store)
    job = _submit(queue, SPEC.model_dump(mode="json"), "slow", max_attempts=2)
    assert run_job(job.id, settings, worker="test", timeout_s=0.2) == "failed"
    failed = queue.get(job.id)
    assert failed.attempts == 2 and "timed out" in failed.error


@pytest.mark.parametrize("when", ["queued", "running"])
def test_cancel(store, settings, when):
    queue = JobQueue(store)
    spec = SPEC.model_copy(update={"frames": 100_000, "resolution": 32})  # outlasts the test
    job = _submit(queue, spec.model_dump(mode="json"), f"cancel-{when}")
    if when == "queued":
        queue.cancel(job.id)
        assert run_job(job.id, settings, worker="test") == "canceled"
        return
    canceler = _cancel_once_rendering(queue, job.id)
    assert run_job(job.id, settings, worker="test") == "canceled"
    canceler.join()
    assert queue.get(job.id).run_id is None


def _cancel_once_rendering(queue: JobQueue, job_id: int) -> threading.Thread:
    """A thread that cancels the job as soon as it renders a seed (its scene loaded,
    its reference made): a running job, not one still starting."""
    def cancel() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if queue.get(job_id).progress.get("stage", "").startswith("seed"):
                queue.cancel(job_id)
                return
            time.sleep(0.05)

    thread = threading.Thread(target=cancel)
    thread.start()
    return thread


def test_a_failed_stage_fails_what_depends_on_it(store, settings):
    """A sweep's reference stage fails (bad input, in the render process); the tasks
    downstream receive its status and fail without running, with its error."""
    from jobs.execution.graph import sweep_stages
    from jobs.protocol.spec import SweepSpec

    queue = JobQueue(store)
    spec = SweepSpec(scene="no-such-scene", seeds=2, eps=[0.5], methods=["nrc"])
    sweep, _ = queue.submit("sweep", spec.model_dump(mode="json"), "sweep")
    stages = queue.stage_jobs(sweep, sweep_stages(spec))
    status = run_job(stages["reference"].id, settings, worker="test")
    assert status == "failed" and "no-such-scene" in queue.get(stages["reference"].id).error
    cache = stages["nrc cache 1/2"]
    assert run_job(cache.id, settings, worker="test", upstream=(status,)) == "failed"
    assert run_job(sweep.id, settings, worker="test", upstream=("failed", "failed")) == "failed"
    for job in (queue.get(cache.id), queue.get(sweep.id)):
        assert job.attempts == 0 and job.error.startswith("stage 'reference' failed:")


@pytest.fixture
def warning_scene(tmp_path) -> str:
    path = tmp_path / "warns.xml"
    path.write_text(WARNING_SCENE)
    return str(path)


def _render_pids() -> set[int]:
    return {p.pid for p in psutil.Process().children(recursive=True) if _is_render_process(p)}


def test_a_job_that_makes_mitsuba_warn_and_the_next_job_both_succeed(store, settings,
                                                                     warning_scene):
    queue = JobQueue(store)
    warns = _submit(queue, {**SPEC.model_dump(mode="json"), "scene": warning_scene}, "warns")
    after = _submit(queue, SPEC.model_dump(mode="json"), "after")
    assert run_job(warns.id, settings, worker="test") == "succeeded"
    child = _render_pids()
    assert run_job(after.id, settings, worker="test") == "succeeded"
    assert _render_pids() == child                  # the same render process served both
    for job in (warns, after):
        done = queue.get(job.id)
        assert done.attempts == 1 and done.error is None and done.run_id is not None


@pytest.mark.parametrize("stop", ["timeout", "cancel"])
def test_a_job_is_stopped_after_mitsuba_warned(store, settings, warning_scene, stop):
    """A warning from the job before, and from the job itself, must not hide its timeout
    or cancel: the stopped job is charged, the job before is not, the child is replaced."""
    queue = JobQueue(store)
    scene = {**SPEC.model_dump(mode="json"), "scene": warning_scene}
    warns = _submit(queue, scene, "warns")
    # Long enough that neither the timeout nor the cancel can come after it finished.
    slow = _submit(queue, {**scene, "frames": 100_000, "resolution": 32}, f"slow-{stop}",
                   max_attempts=1)
    assert run_job(warns.id, settings, worker="test") == "succeeded"
    child = _render_pids()
    if stop == "timeout":
        assert run_job(slow.id, settings, worker="test", timeout_s=2.0) == "failed"
        assert "timed out" in queue.get(slow.id).error
    else:
        canceler = _cancel_once_rendering(queue, slow.id)    # after its own warning
        assert run_job(slow.id, settings, worker="test") == "canceled"
        canceler.join()
    assert queue.get(slow.id).run_id is None
    done = queue.get(warns.id)
    assert done.status == "succeeded" and done.error is None and done.attempts == 1
    assert not child & _render_pids()               # the stopped child is gone


def test_a_render_process_that_exits_on_its_own_is_reported_by_its_exit_status():
    """Before: when a render process closed its status pipe while still exiting, the
    runner killed it at once and reported "killed by SIGKILL" for a process that was
    ending on its own. After: it is given time to exit and its own status is named."""
    read, write = os.pipe()
    process = subprocess.Popen(
        [sys.executable, "-c", f"import os, time; os.close({write}); time.sleep(0.5); "
                               "raise SystemExit(7)"], pass_fds=(write,))
    os.close(write)
    child = object.__new__(_Child)      # a stand-in process in the render process's place
    child.proc, child.log, child.status = process, tempfile.TemporaryFile("w+"), os.fdopen(read)
    assert child.status.readline() == ""            # the pipe closed: it is ending
    assert child.close(ended=True) == "the render process exited with status 7"
