"""Methods from outside the repository (entry-point group ``nirc_bench.methods``).

The example package tests/plugins/nirc_bench_example_method is made visible the way
an installed package is: a ``*.dist-info`` folder with its ``entry_points.txt``
(written from the package's own pyproject.toml) on the path, which
importlib.metadata discovers. A second, broken package registers entry points that
fail to import, are not a Method, take a built-in's name or misname their method.
A fresh interpreter then reads the registry (the sweep spec's method list is fixed
at import), renders the example method through the executor, lists it in
``GET /api/v1/methods``, queues it as a render job and validates a sweep over the
example caching method.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "tests" / "plugins" / "nirc_bench_example_method"

BROKEN = {
    "broken-import": "nirc_bench_no_such_module:METHOD",
    "not-a-method": "json:dumps",
    "pt": "renderers.methods.pt:METHOD",
    "misnamed": "nirc_bench_example_method:DIRECT",
}

SCRIPT = r"""
import json, sys
from pathlib import Path

from fastapi.testclient import TestClient
from pydantic import ValidationError

from jobs.execution.apikeys import create_api_key
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec, SweepSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from renderers.backend import init_backend
from renderers.methods import METHODS, METHOD_SOURCES, SKIPPED_PLUGINS, sweep_methods
from service.api.main import create_app

init_backend()
settings = Settings(data_dir=Path(sys.argv[1]))
store = open_store(settings)
spec = RenderSpec(scene="cornell-box", method="example-direct", resolution=16, spp=1,
                  frames=2, seeds=2, reference=ReferenceSpec(spp=64, spp_per_pass=16))
summary = execute(RenderJob.parse(spec), store, settings)
run = store.get_run(summary.run_id)
_, key = create_api_key(store, "plugin test")
with TestClient(create_app(settings)) as http:
    methods = http.get("/api/v1/methods").json()
    result = http.get(f"/api/v1/runs/{run.id}").json()
    job = http.post("/api/v1/jobs", headers={"X-API-Key": key},
                    json={"scene": "cornell-box", "method": "example-direct", "resolution": 8})
    deep = http.post("/api/v1/jobs", headers={"X-API-Key": key},
                     json={"scene": "cornell-box", "method": "example-direct",
                           "resolution": 8, "params": {"max_depth": 3}})
    sweep = http.post("/api/v1/sweeps", headers={"X-API-Key": key},
                      json={"scene": "cornell-box", "methods": ["example-nirc"],
                            "eps": [0.5], "resolution": 8})
try:
    SweepSpec(scene="cornell-box", methods=["example-direct"], eps=[0.5])
    refused = ""
except ValidationError as err:
    refused = str(err)
print(json.dumps({
    "methods": list(METHODS), "sweep_methods": list(sweep_methods()),
    "sources": METHOD_SOURCES, "skipped": SKIPPED_PLUGINS, "api": methods,
    "run": {"method": result["method"], "estimator_version": result["estimator_version"],
            "verdict": result["verdict"], "mrse": result["mrse"],
            "params": result["params"], "ref_max_depth": run.reference is not None
            and store.get_reference(run.reference_id).max_depth},
    "job": [job.status_code, job.json()], "deep": [deep.status_code, deep.json()], "sweep": [sweep.status_code, sweep.json()],
    "refused": refused}))
"""


def _dist_info(folder: Path, name: str, entry_points: dict[str, str]) -> None:
    """An installed distribution as importlib.metadata sees one: METADATA and entry points."""
    info = folder / f"{name}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    lines = ["[nirc_bench.methods]"] + [f"{k} = {v}" for k, v in entry_points.items()]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def plugin_session(tmp_path_factory):
    """What a fresh interpreter with the example and the broken package sees and does."""
    tmp = tmp_path_factory.mktemp("plugins")
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    _dist_info(tmp / "site", project["name"].replace("-", "_"),
               project["entry-points"]["nirc_bench.methods"])
    _dist_info(tmp / "site", "nirc_bench_broken_plugins", BROKEN)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp / "site"),
                                                        str(PLUGIN)])}
    env.pop("NIRC_BENCH_DATABASE_URL", None)
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp / "data")], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


def test_a_plugin_method_is_registered_after_the_builtins(plugin_session):
    seen, _ = plugin_session
    assert seen["methods"][-2:] == ["example-direct", "example-nirc"]
    assert seen["methods"][0] == "pt"
    assert seen["sources"]["example-direct"].startswith(
        "entry point example-direct = nirc_bench_example_method:DIRECT")
    assert "nirc_bench_example_method 0.1" in seen["sources"]["example-direct"]


def test_bad_entry_points_are_left_out_with_the_reason_and_logged(plugin_session):
    seen, stderr = plugin_session
    skipped = seen["skipped"]
    assert set(skipped) == {f"{k} = {v}" for k, v in BROKEN.items()}
    assert skipped["broken-import = nirc_bench_no_such_module:METHOD"].startswith(
        "could not be loaded: ModuleNotFoundError")
    assert skipped["not-a-method = json:dumps"] == \
        "it is a function, not a renderers.methods.Method"
    assert skipped["pt = renderers.methods.pt:METHOD"] == "'pt' is a built-in method's name"
    assert skipped["misnamed = nirc_bench_example_method:DIRECT"].startswith(
        "it declares the method 'example-direct'")
    assert stderr.count("left out") == len(BROKEN)
    assert seen["api"]["skipped_plugins"] == skipped


def test_a_plugin_method_renders_through_the_executor(plugin_session):
    run = plugin_session[0]["run"]
    assert run["method"] == "example-direct" and run["estimator_version"] == 1
    assert run["params"]["max_depth"] == 2 and run["ref_max_depth"] == 2
    assert run["verdict"] == "ok" and 0 < run["mrse"] < 10


def test_the_service_lists_queues_and_sweeps_plugin_methods(plugin_session):
    seen, _ = plugin_session
    listed = {m["name"]: m for m in seen["api"]["methods"]}
    assert listed["example-direct"]["label"] == "direct"
    assert listed["example-nirc"]["sweep"] == "example NIRC"
    assert listed["pt"]["source"] == "built-in"
    status, job = seen["job"]
    assert status == 202 and job["spec"]["method"] == "example-direct", job
    # Its parameter model validates the job: depth 3 is beyond direct lighting.
    status, body = seen["deep"]
    assert status == 422 and "max_depth" in json.dumps(body)
    assert "example-nirc" in seen["sweep_methods"]
    assert seen["sweep"][0] == 202, seen["sweep"]
    assert "example-nirc" in seen["refused"]     # the list of sweep methods names it
