"""Animated scenes over REST and in the run's table: a job names a built-in animated
scene, an invalid animation is 422 with the spec's message, and the stored run's table
(what `render` and `runs show` print) shows the per-frame error, the recovery after the
change with its interval, the flicker and the scene-update cost."""

from __future__ import annotations

import pytest
from rich.console import Console

from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.results import RunResultDetail
from jobs.protocol.spec import RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.tables import metrics_table
from tests.service.test_api import ThreadDispatcher, _api

#: cornell-box-sudden changes at frame 8: frames 8-12 are the segment after it (the
#: steady window of 4 frames and one before it). 4x4 pixels, 2 seeds, a small reference.
ANIMATED = {"scene": "cornell-box-sudden", "method": "pt", "resolution": 4, "spp": 1,
            "frames": 13, "seeds": 2, "reference": {"spp": 16, "spp_per_pass": 16}}


@pytest.fixture
def api(data_folder, monkeypatch):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    # Jobs stay queued: what runs them is the executor's, tested below in-process.
    monkeypatch.setattr(ThreadDispatcher, "submit", lambda self, job: None)
    yield from _api(Settings(data_dir=data_folder))


def _text(renderable) -> str:
    console = Console(width=200, record=True)
    console.print(renderable)
    return console.export_text()


@pytest.mark.parametrize(("animation", "message"), [
    ({"emitters": [{"emitter": "light", "frame": 2, "scale": -1.0}]}, "greater than or equal"),
    ({"camera": [{"frame": 3, "position": [0, 0, 1], "target": [0, 0, 0]},
                 {"frame": 1, "position": [0, 0, 2], "target": [0, 0, 0]}]},
     "strictly increasing frames"),
])
def test_an_invalid_animation_is_422_with_the_specs_message(api, animation, message):
    client = api[0]
    response = client.post("/api/v1/jobs", json={**ANIMATED, "scene": "cornell-box",
                                                 "animation": animation})
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert any(item["loc"][:2] == ["body", "animation"] and message in item["msg"]
               for item in detail), detail
    assert client.get("/api/v1/jobs").json() == []


def test_an_animation_of_an_animated_scene_is_422(api):
    client = api[0]
    response = client.post("/api/v1/jobs", json={
        **ANIMATED, "animation": {"emitters": [{"emitter": "light", "frame": 1, "scale": 0}]}})
    assert response.status_code == 422, response.text
    assert "animated already" in response.text


def test_a_method_whose_state_an_update_leaves_stale_is_422_with_the_reason(api):
    """door-sudden moves the door: the grid cache, whose cell edge is sized once from the
    scene's extent, is refused; cornell-box-sudden (a light change) it takes."""
    client = api[0]
    response = client.post("/api/v1/jobs", json={**ANIMATED, "scene": "door-sudden",
                                                 "method": "grid-cache"})
    assert response.status_code == 422, response.text
    assert "cell edge is sized from the scene's extent" in response.text
    taken = client.post("/api/v1/jobs", json={**ANIMATED, "method": "grid-cache"})
    assert taken.status_code == 202, taken.text


def test_a_job_names_an_animated_scene_and_is_queued(api):
    client = api[0]
    response = client.post("/api/v1/jobs", json=ANIMATED)
    assert response.status_code == 202, response.text
    queued = client.get(f"/api/v1/jobs/{response.json()['id']}").json()
    assert queued["spec"]["scene"] == "cornell-box-sudden", queued


def test_an_animated_runs_table_shows_frames_recovery_and_the_update(data_folder, mi):
    """The table `render` prints and `runs show` starts with, of a stored animated run."""
    settings = Settings(data_dir=data_folder)
    store = open_store(settings)
    summary = execute(RenderJob.parse(RenderSpec.model_validate(ANIMATED)), store, settings)
    run = RunResultDetail.of(store.get_run(summary.run_id))   # as `runs show` reads it
    store.close()
    animation = run.metrics["animation"]
    assert animation["change_frames"] == [8]
    text = _text(metrics_table(run))
    curve = animation["frame_mrse"]["mean"]
    # Each segment's first and last frame, with its error as stored.
    for frame in (0, 7, 8, 12):
        assert f"{curve[frame]:.4g}" in text, (frame, text)
    recovered = animation["recovery"][0]
    assert recovered["low"] is not None
    assert f"[{recovered['low']:.3g}, {recovered['high']:.3g}]" in text
    flicker = animation["flicker"]
    assert flicker["seeds"] == 2 and flicker["low"] < flicker["mean"] < flicker["high"]
    assert f"{flicker['mean']:.4g} [{flicker['low']:.4g}, {flicker['high']:.4g}]" in text
    assert 0 < flicker["static_fraction"] <= 1
    assert len(animation["frame_flip"]["mean"]) == ANIMATED["frames"]
    assert "scene update (outside the frame time): " in text
    assert f"{animation['scene_update']['updates']} updates" in text
