"""A run's float pixels over REST (GET /api/v1/runs/{id}/pixels/{layer}) and the chart
specs (GET /api/v1/charts/...): true values with their shape, the bias and variance
maps consistent with rBias² and rVar, bad input answered 4xx in JSON; the vendored
image slider matches its recorded checksums."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from jobs.execution.work import IMAGE_BYTES_PER_PIXEL, PIXEL_MAPS, render_work
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.artifacts import RELATIVE_BIAS_MAP, RELATIVE_VARIANCE_MAP, ArtifactStore
from jobs.record.config import Settings
from jobs.record.db import open_store
from metrics.errors import relative_squared_error_map
from metrics.imageio import read_exr
from service.api.main import DASHBOARD_DIR, create_app

SPEC = RenderSpec(scene="cornell-box", resolution=16, spp=1, frames=2, seeds=3,
                  reference=ReferenceSpec(spp=64, spp_per_pass=8))


@pytest.fixture(scope="module")
def served(tmp_path_factory, mi):
    """(client, store, settings, [3-seed run at 16², 1-seed run at 12², 1 frame])."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("pixels") / "data")
    store = open_store(settings)
    runs = [execute(RenderJob.parse(spec), store, settings).run_id for spec in
            (SPEC, SPEC.model_copy(update={"resolution": 12, "seeds": 1, "frames": 1}))]
    with TestClient(create_app(settings)) as client:
        yield client, store, settings, runs
    store.close()


def pixels(client: TestClient, path: str) -> np.ndarray:
    answer = client.get(path)
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"] == "application/octet-stream"
    shape = [int(answer.headers[h]) for h in ("X-Height", "X-Width", "X-Channels")]
    return np.frombuffer(answer.content, dtype="<f4").reshape(shape)


def test_layers_are_the_stored_values(served):
    client, store, settings, (run_id, _) = served
    run = store.get_run(run_id)
    ref = read_exr(settings.references_dir / run.reference.image_path)
    np.testing.assert_array_equal(pixels(client, f"/api/v1/runs/{run_id}/pixels/reference"), ref)
    seed = next(s for s in run.seed_results if s.seed == 1)
    stored = next(a for a in seed.artifacts if a.kind == "image")
    image = read_exr(ArtifactStore(settings.artifacts_dir).path_of(stored.path))
    np.testing.assert_array_equal(
        pixels(client, f"/api/v1/runs/{run_id}/pixels/image?seed=1"), image)
    error = pixels(client, f"/api/v1/runs/{run_id}/pixels/error?seed=1")
    np.testing.assert_allclose(error[..., 0], relative_squared_error_map(image, ref, SPEC.eps))
    assert "relative squared error" in client.get(
        f"/api/v1/runs/{run_id}/pixels/error").headers["X-Quantity"]


def test_bias_and_variance_maps_add_up_to_the_run_metrics(served):
    client, store, _, (run_id, _) = served
    metrics = store.get_run(run_id).metrics
    bias = pixels(client, f"/api/v1/runs/{run_id}/pixels/bias").astype(np.float64)
    variance = pixels(client, f"/api/v1/runs/{run_id}/pixels/variance").astype(np.float64)
    assert bias.shape == variance.shape == (16, 16, 3)
    assert np.mean(bias ** 2) == pytest.approx(metrics["rbias2_raw"], rel=1e-4)
    assert np.mean(variance) == pytest.approx(metrics["rvar"], rel=1e-4)


def test_bad_input_is_a_4xx_in_json(served):
    client, _, _, (run_id, one_seed) = served
    for path, code in ((f"/api/v1/runs/{run_id}/pixels/nope", 422),
                       (f"/api/v1/runs/{run_id}/pixels/image?seed=-1", 422),
                       (f"/api/v1/runs/{run_id}/pixels/image?seed=x", 422),
                       (f"/api/v1/runs/{run_id}/pixels/image?seed=99", 404),
                       ("/api/v1/runs/99999/pixels/reference", 404),
                       ("/api/v1/runs/0/pixels/reference", 422),
                       (f"/api/v1/runs/{one_seed}/pixels/bias", 404),
                       ("/api/v1/charts/runs/99999", 404), ("/api/v1/charts/sweeps/99999", 404),
                       ("/api/v1/charts/scene", 422), ("/api/v1/charts/history?scene=a", 422)):
        answer = client.get(path)
        assert answer.status_code == code, (path, answer.text)
        assert "detail" in answer.json(), path
    assert "its seeds: 0, 1, 2" in client.get(
        f"/api/v1/runs/{run_id}/pixels/image?seed=99").json()["detail"]
    assert "2 or more seeds" in client.get(
        f"/api/v1/runs/{one_seed}/pixels/bias").json()["detail"]


def test_scene_charts_draw_one_group_per_resolution(served):
    client, _, _, (run_id, one_seed) = served
    groups = client.get("/api/v1/charts/scene?scene=cornell-box").json()["groups"]
    assert [group["runs"] for group in groups] == [[run_id], [one_seed]]
    assert "16×16" in groups[0]["title"] and "12×12" in groups[1]["title"]
    assert all(len(group["charts"]) == 2 for group in groups)          # MRSE and FLIP
    convergence = client.get(f"/api/v1/charts/runs/{one_seed}").json()
    assert convergence["convergence"] is None and "one frame" in convergence["note"]
    assert client.get(f"/api/v1/charts/runs/{run_id}").json()["convergence"]["encoding"] \
        ["x"]["axis"]["values"] == [0, 1]


def test_the_maps_count_in_the_data_budget(served):
    _, store, _, (run_id, one_seed) = served
    kinds = {RELATIVE_BIAS_MAP, RELATIVE_VARIANCE_MAP}
    assert {a.kind for a in store.get_run(run_id).artifacts} >= kinds
    assert not {a.kind for a in store.get_run(one_seed).artifacts} & kinds
    with_maps, without = render_work(SPEC, True), render_work(SPEC.model_copy(update={"seeds": 1}), True)
    pixels_ = SPEC.resolution ** 2
    assert with_maps.artifact_bytes - without.artifact_bytes == \
        pixels_ * IMAGE_BYTES_PER_PIXEL * (2 + PIXEL_MAPS)


def test_the_vendored_slider_matches_its_recorded_checksums():
    folder = DASHBOARD_DIR / "vendor" / "img-comparison-slider"
    source = json.loads((folder / "SOURCE.json").read_text())
    assert source["version"] == "8.0.7" and source["tarball_integrity"].startswith("sha512-")
    for name, entry in source["files"].items():
        assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == entry["sha256"], name
    assert "MIT License" in (folder / "LICENSE").read_text()
