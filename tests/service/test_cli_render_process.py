"""``nirc-bench render`` renders in a process of its own (jobs/execution/embedded.py):
a native crash there fails the job with a record and a one-line message instead of
killing the command, and a render that works stores what rendering in process stored."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from jobs.execution.queue import JobQueue
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from tests.renderers.test_method_plugins import _dist_info
from tests.service.test_cli import run_cli

#: A method that aborts its render process (as heap corruption or a failed Dr.Jit
#: assertion does), registered through the method entry points.
ABORTING_METHOD = '''
import os

from renderers.methods import Method, pt


def render(*args, **kwargs):
    os.abort()


METHOD = Method("abort", "aborts the render process", pt.PTParams, render, version=1)
'''

TINY = ("--scene", "cornell-box", "--res", "8", "--spp", "1", "--ref-spp", "64")


@pytest.fixture
def aborting_method(tmp_path: Path) -> dict[str, str]:
    """The environment of a CLI that has the method 'abort' (and of its render process)."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "nirc_bench_abort_method.py").write_text(ABORTING_METHOD)
    _dist_info(site, "nirc_bench_abort_method", {"abort": "nirc_bench_abort_method:METHOD"})
    return {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}


def test_a_render_process_that_aborts_fails_the_job_with_a_record(tmp_path, aborting_method):
    data = tmp_path / "data"
    proc = run_cli("render", *TINY, "--method", "abort", "--frames", "1", "--seeds", "1",
                   data_dir=data, env=aborting_method)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    message = proc.stderr.strip().splitlines()[-1]
    assert message.startswith("nirc-bench: render failed: the render process was killed by "
                              "SIGABRT during stage 'seed 1/1' (0/1)"), proc.stderr
    assert message.endswith("the job is stored as failed (job 1)"), message
    store = open_store(Settings(data_dir=data))
    job = JobQueue(store).get(1)
    assert job.status == "failed" and job.attempts == 1 and job.run_id is None
    assert "killed by SIGABRT during stage 'seed 1/1'" in job.error
    assert store.list_runs() == []
    store.close()


@pytest.mark.slow
def test_a_render_stores_what_rendering_in_process_stores(tmp_path, monkeypatch):
    """The same spec through the CLI's render process and through ``execute`` in this
    process: the same seeds' images bit for bit, the same metrics and the same summary
    fields; the reference rendered by the first is reused by the second, and each says so."""
    data = tmp_path / "data"
    proc = run_cli("render", *TINY, "--frames", "2", "--seeds", "2", "--json", data_dir=data)
    assert proc.returncode == 0, proc.stderr
    embedded = json.loads(proc.stdout)
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(data))
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings()
    store = open_store(settings)
    spec = RenderSpec(scene="cornell-box", resolution=8, spp=1, frames=2, seeds=2,
                      reference=ReferenceSpec(spp=64))
    here = execute(RenderJob.parse(spec), store, settings).to_json()
    assert embedded["reference"]["rendered_now"] and not here["reference"]["rendered_now"]
    assert not embedded["reused"] and not here["reused"]
    assert embedded.keys() == here.keys() and embedded["spec"] == here["spec"]
    assert embedded["reference"]["key"] == here["reference"]["key"]
    for ours, theirs in zip(embedded["per_seed"], here["per_seed"], strict=True):
        ours.pop("seconds_per_frame"), theirs.pop("seconds_per_frame")
        assert ours == theirs
    assert embedded["metrics"]["rbias2"] == here["metrics"]["rbias2"]
    images = [{seed.seed: a.sha256 for seed in store.get_run(run_id).seed_results
               for a in seed.artifacts if a.kind == "image"}
              for run_id in (embedded["run_id"], here["run_id"])]
    assert images[0] == images[1] and len(images[0]) == 2
    store.close()
