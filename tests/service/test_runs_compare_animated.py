"""``nirc-bench runs compare`` of animated runs, stored with synthetic per-frame errors
(tests/jobs/animation_factories.py): per change both runs' recovery with its interval
and whether they differ, per segment both steady errors, both runs' flicker; an animated
run beside a static one is called not comparable."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jobs.protocol.flicker import run_flicker
from jobs.record.config import Settings
from jobs.record.db import open_store
from tests.jobs.animation_factories import animation_metrics
from tests.jobs.factories import run_fields
from tests.service.test_runs_cli import cli

SCENE = "cornell-box-sudden"      # the light jumps to 4x at frame 8
FRAMES, SEEDS = 20, 6


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Runs 1 and 2 recover in ~2 frames, run 3 in ~7 (a planted slow cache; 1 and 2
    differ only in their noise), run 4 is static. Over 30 draws of the noise the
    intervals told 3 from 1 in 29 and 2 from 1 in none. Runs 1 and 2 flicker 0.2 per
    seed, run 3 twice as much (10 % noise per seed)."""
    data = tmp_path_factory.mktemp("compare-animated") / "data"
    store = open_store(Settings(data_dir=data))
    rng = np.random.default_rng(7)
    for seed, (decay, flicker) in enumerate(((0.5, 0.2), (0.5, 0.2), (2.0, 0.4))):
        animation = animation_metrics(SCENE, FRAMES, seeds=SEEDS, steady=0.1, jump=3.0,
                                      decay_frames=decay, noise=0.05, seed=seed)
        animation["flicker"] = run_flicker(
            (flicker * rng.lognormal(0.0, 0.1, SEEDS)).tolist(), [0.9])
        store.add_run(run_fields(scene_name=SCENE, frames=FRAMES, seeds=SEEDS,
                                 metrics={"mrse": 0.1, "animation": animation}), [])
    store.add_run(run_fields(scene_name="cornell-box", frames=FRAMES, seeds=SEEDS), [])
    store.close()
    return data


def animation_delta(data, *ids: str) -> dict:
    comparison = json.loads(cli("runs", "compare", *ids, "--json", data=data))
    [delta] = comparison["animation"]
    return delta


def test_compare_reports_both_recoveries_and_tells_a_slow_cache_apart(data):
    same = animation_delta(data, "1", "2")
    [change] = same["changes"]
    assert (change["change_frame"], change["label"]) == (8, "light x4")
    assert change["differs"] is False                   # the same recovery, other noise
    slow = animation_delta(data, "1", "3")["changes"][0]
    assert slow["run"]["frames"] > slow["baseline"]["frames"]
    assert slow["baseline"]["high"] < slow["run"]["low"] and slow["differs"] is True
    segments = animation_delta(data, "1", "3")["segments"]
    assert [(s["first"], s["last"]) for s in segments] == [(0, 7), (8, FRAMES - 1)]
    # Both settle at the same level: the steady errors agree within the noise.
    assert all(s["run"] == pytest.approx(s["baseline"], rel=0.2) for s in segments)
    assert animation_delta(data, "1", "2")["flicker"]["differs"] is False
    flicker = animation_delta(data, "1", "3")["flicker"]
    assert flicker["baseline"]["high"] < flicker["run"]["low"] and flicker["differs"] is True
    table = cli("runs", "compare", "1", "3", data=data)
    for fragment in ("recovery after each change", "light x4", "steady MRSE per segment",
                     "differs", f"flicker: run 1 {flicker['baseline']['mean']:.3g}",
                     "differs: yes"):
        assert fragment in table


def test_an_animated_run_beside_a_static_one_is_not_comparable(data):
    delta = animation_delta(data, "4", "1")
    assert not delta["comparable"] and delta["changes"] == []
    assert "run 1 is animated, run 4 static" in delta["note"]
    assert "not comparable" in cli("runs", "compare", "1", "4", data=data)
