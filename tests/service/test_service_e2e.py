"""The service end to end, as a user meets it: on a fresh data folder `nirc-bench
serve` (embedded defaults) runs a sweep submitted with `nirc-bench sweep --server`
as its task graph (reference, then the caches, then the points, then the sweep),
and the sweep's curves appear on the dashboard in a real Chromium. On SQLite and
PostgreSQL."""

from __future__ import annotations

import json
import subprocess
import sys

from jobs.execution.graph import sweep_stages
from jobs.protocol.spec import SweepSpec
from tests.service.conftest import ARTIFACTS, open_page, wait_until
from tests.service.live import Service

SWEEP = ["--scene", "cornell-box", "--eps", "0.3,1.0", "--nc", "1,2", "--res", "12",
         "--seeds", "2", "--train-frames", "3", "--v1-spp", "16", "--ref-spp", "64",
         "-p", 'cache={"batch_size": 1024}', "-p", "min_train_paths=1024",
         "--allow-loaded"]     # equal-time probes count on the shared, loaded test machine


def test_a_sweep_submitted_over_rest_runs_as_a_task_graph_and_reaches_the_dashboard(
        tmp_path, chromium, database_url):
    service = Service(tmp_path / "data", database_url=database_url)
    service.start()
    try:
        cli = subprocess.run(
            [sys.executable, "-m", "service", "sweep", *SWEEP, "--server", service.url,
             "--api-key", service.key, "--json"],
            capture_output=True, text=True, timeout=900)
        assert cli.returncode == 0, cli.stderr
        result = json.loads(cli.stdout)
        assert {row["series"] for row in result["result"]["rows"]} \
            == {"NIRC", "NRC", "NIRC equal time"}

        jobs = service.get("/api/v1/jobs?limit=100")
        (parent,) = [job for job in jobs if job["kind"] == "sweep"]
        detail = service.get(f"/api/v1/jobs/{parent['id']}")
        spec = SweepSpec(**parent["spec"])
        assert [stage["name"] for stage in detail["stages"]] \
            == [stage.name for stage in sweep_stages(spec)]
        assert {stage["status"] for stage in detail["stages"]} == {"succeeded"}
        stages = [job for job in jobs if job["parent_id"] == parent["id"]]
        # The sweep job ran after every stage; every cache after the reference.
        assert max(job["finished_at"] for job in stages) <= detail["started_at"]
        by_name = {job["spec"]["name"]: job for job in stages}
        assert all(by_name["reference"]["finished_at"] <= job["started_at"]
                   for name, job in by_name.items() if name != "reference")
        assert detail["sweep_id"] == result["id"]
        # What the stages rendered is summed into the sweep's result.
        stage_work = result["result"]["stage_work"]
        assert (stage_work["reference_rendered"], stage_work["snapshots_trained"],
                stage_work["points_rendered"]) == (1, 4, 4)
        assert by_name["reference"]["work"]["reference_rendered"] == 1
        assert {stage["name"]: (stage["work"]["snapshots_trained"],
                                stage["work"]["points_rendered"])
                for stage in detail["stages"] if stage["name"] != "reference"} \
            == {"nirc cache 1/2": (1, 0), "nirc cache 2/2": (1, 0), "nirc points": (0, 2),
                "nrc cache 1/2": (1, 0), "nrc cache 2/2": (1, 0), "nrc points": (0, 2)}

        # The same sweep again, as a table: the service returns the finished job.
        again = subprocess.run(
            [sys.executable, "-m", "service", "sweep", *SWEEP, "--server", service.url,
             "--api-key", service.key], capture_output=True, text=True, timeout=300)
        assert again.returncode == 0, again.stderr
        assert f"job {parent['id']} submitted" in again.stdout
        assert "NIRC equal time" in again.stdout and "7 stage jobs" in again.stdout
        assert "rendered by its stage jobs: reference 1, caches 4 (reused 4), points 4 (reused 0)" \
            in again.stdout
        assert f"{service.url}/api/v1/artifacts/" in again.stdout    # the plots' URLs

        page, errors = open_page(chromium, f"{service.url}/#/scene/cornell-box")
        wait_until(page, "document.body.dataset.ready !== undefined")
        assert page.locator("#sweep .vega-embed g.mark-symbol.role-mark path").count() > 0
        assert f"sweep {result['id']}" in page.locator("#sweep .role-title-text").first \
            .text_content()
        ARTIFACTS.mkdir(exist_ok=True)
        name = f"dashboard-e2e-sweep-{'postgresql' if database_url else 'sqlite'}.png"
        page.screenshot(path=str(ARTIFACTS / name), full_page=True)
        assert errors == []
    finally:
        service.stop()
