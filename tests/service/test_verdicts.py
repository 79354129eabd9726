"""Verdicts and versions where users see them: the CLI (table and --json), the run and
results endpoints, and compare, which refuses runs of different metric versions."""

from __future__ import annotations

import json

from metrics import METRIC_VERSION
from tests.jobs.factories import run_fields
from tests.jobs.test_quality import SCENE
from tests.service.test_cli import run_cli

NO_EMITTER = {"verdict": "no-emitter", "withheld": ["mrse"], "finite": True,
              "nonfinite_pixels": 0,
              "reasons": [{"code": "no-emitter", "message": "the scene has no emitter",
                           "withheld": ["mrse"]}]}


def test_verdict_and_versions_are_served(api_and_store):
    http, store = api_and_store
    current = store.add_run(run_fields(quality=NO_EMITTER, estimator_version=2,
                                       metric_version=METRIC_VERSION))
    old = store.add_run(run_fields(method="pt"))            # stored before versions: 1 / 1
    run = http.get(f"/api/v1/runs/{current.id}").json()
    assert run["verdict"] == "no-emitter" and run["withheld"] == ["mrse"]
    assert run["quality"]["reasons"][0]["code"] == "no-emitter"
    assert (run["estimator_version"], run["metric_version"], run["current"]) == (2, METRIC_VERSION, True)

    listed = http.get("/api/v1/results").json()
    assert [r["id"] for r in listed] == [current.id] and listed[0]["verdict"] == "no-emitter"
    every = http.get("/api/v1/results", params={"include_old": True}).json()
    assert {r["id"]: r["current"] for r in every} == {current.id: True, old.id: False}
    assert next(r for r in every if r["id"] == old.id)["verdict"] is None


def test_compare_refuses_mixed_metric_versions_and_flags_estimators(api_and_store):
    http, store = api_and_store
    new = store.add_run(run_fields(estimator_version=2, metric_version=METRIC_VERSION))
    old_metric = store.add_run(run_fields(estimator_version=2, metric_version=1))
    old_pt = store.add_run(run_fields(estimator_version=1, metric_version=METRIC_VERSION))
    refused = http.get("/api/v1/compare", params={"runs": f"{new.id},{old_metric.id}"})
    assert refused.status_code == 422
    assert "different metric definitions" in refused.json()["detail"][0]["msg"]
    flagged = http.get("/api/v1/compare", params={"runs": f"{new.id},{old_pt.id}"}).json()
    assert flagged["estimator_versions"] == {"pt": [1, 2]} and flagged["metric_version"] == METRIC_VERSION
    assert "pt runs of estimator versions 1, 2 are different estimators" in flagged["note"]


def test_cli_prints_the_verdict(tmp_path, mi):
    scene = tmp_path / "dark.xml"
    scene.write_text(SCENE.format(emitter=""))
    args = ("render", "--scene", str(scene), "--res", "8", "--seeds", "2", "--ref-spp", "16")
    proc = run_cli(*args, "--json", data_dir=tmp_path / "data")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["quality"]["verdict"] == "no-emitter"
    assert summary["metrics"]["mrse_mean"] is None and summary["metric_version"] == METRIC_VERSION
    table = run_cli(*args, data_dir=tmp_path / "data")
    assert table.returncode == 0, table.stderr
    assert "no-emitter" in table.stdout and "withheld" in table.stdout
