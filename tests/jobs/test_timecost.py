"""A job's time estimated from this device's measured costs (jobs/execution/timecost.py):
stored runs and references of the method on the scene, else the stated default."""

from __future__ import annotations

import pytest

from jobs.execution.timecost import DEFAULT, estimate_seconds, fit
from jobs.execution.work import render_work
from jobs.protocol.spec import RenderSpec
from renderers.backend import cpu_device_key
from tests.jobs.factories import reference_fields, run_fields

SPEC = RenderSpec(scene="cornell-box", method="pt", resolution=64, spp=1, frames=10_000,
                  seeds=4, reference={"spp": 64, "spp_per_pass": 8})


def _run(store, width: int, spp: int, seconds_per_frame: float, device_key: str) -> None:
    store.add_run(run_fields(width=width, height=width, spp=spp, device_key=device_key,
                             timings={"seconds_per_frame": seconds_per_frame,
                                      "warmup_s": 0.2}), [], [])


def test_without_measurements_the_default_holds(store):
    work = render_work(SPEC)
    estimate = estimate_seconds(work, ["pt"], "cornell-box", store)
    seeds = 4 * DEFAULT.start_s + 40_000 * DEFAULT.frame_s + 64 * 64 * 40_000 * DEFAULT.sample_s
    assert estimate.parts["seeds"] == pytest.approx(seeds)
    assert estimate.sources["seeds"] == DEFAULT.source


def test_measured_runs_on_this_device_set_the_costs(store):
    """Frames of two sizes fit a line: 2 ms + 1e-7 s per sample; runs of another
    device are ignored."""
    here = cpu_device_key()
    for width, spp in ((16, 1), (64, 4), (64, 16)):
        _run(store, width, spp, 0.002 + 1e-7 * width * width * spp, here)
    _run(store, 64, 1, 5.0, "llvm:some other cpu:64")
    estimate = estimate_seconds(render_work(SPEC), ["pt"], "cornell-box", store)
    frames = 40_000 * (0.002 + 1e-7 * 64 * 64)
    assert estimate.parts["seeds"] == pytest.approx(4 * 0.2 + frames, rel=1e-6)
    assert "3 stored runs" in estimate.sources["seeds"]
    # Far below the default's estimate: the measurement, not the default, decides.
    assert estimate.seconds < estimate_seconds(render_work(SPEC), ["nrc"], "cornell-box",
                                               store).seconds / 5


def test_one_measured_size_covers_smaller_frames_and_adds_the_default_beyond(store):
    costs = fit([(4096.0, 0.01)], [], "one run")
    assert costs.seconds(0, 10, 10 * 1024) == pytest.approx(0.1)
    assert costs.seconds(0, 10, 10 * 8192) == pytest.approx(0.1 + 10 * 4096 * DEFAULT.sample_s)


def test_references_measure_the_reference_part(store):
    here = cpu_device_key()
    store.add_reference(**reference_fields("r", width=64, height=64, spp=4096, passes=64,
                                           render_seconds=6.4, device={"device_key": here}))
    estimate = estimate_seconds(render_work(SPEC), ["pt"], "cornell-box", store)
    # One size of pass (64x64 x 64 spp) measured at 0.1 s: the job's 8 smaller passes.
    assert estimate.parts["reference"] == pytest.approx(DEFAULT.start_s + 8 * 0.1)
