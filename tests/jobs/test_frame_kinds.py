"""Readers of stored frames take wall times from wall frames and kernel times from kernel
frames (renderers.timing.frame_kind): the cost model's probe samples and pareto's stored
frame times. The kernel and after-kernel frames below are slower (the history's cost),
so a reader that took every frame would read another value."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from jobs.costs.cost_model import Probe, sample_of
from jobs.pareto.pareto import stored_frame_times
from renderers.timing import AFTER_KERNEL, FrameTime


def frames(shift: float = 0.0) -> list[FrameTime]:
    """W K A W, twice: wall render 10, 11, 12, 13 ms; kernel frames 30 ms wall, 8 and 9
    ms of kernels; after-kernel frames 40 ms."""
    def wall(ms: float) -> FrameTime:
        return FrameTime(stages={"render": 1e-3 * (ms + shift)}, whole_s=1e-3 * (ms + 1))

    def kernel(ms: float) -> FrameTime:
        return FrameTime(stages={"render": 0.030}, whole_s=0.031,
                         kernel_s={"render": 1e-3 * ms, "other": 0.0},
                         launches={"render": 3})

    after = FrameTime(stages={"render": 0.040}, whole_s=0.041, kind=AFTER_KERNEL)
    return [wall(10), kernel(8), after, wall(11), wall(12), kernel(9), after, wall(13)]


def test_a_probe_sample_takes_wall_times_from_wall_frames_and_kernels_from_kernel_frames():
    sample = sample_of(Probe(8), frames(), {"render": 64.0, "other": 64.0})
    assert sample.frame_s == pytest.approx(0.011)          # lower median of 10..13 ms
    assert sample.wall_s["render"] == pytest.approx(0.011)
    assert sample.kernel_s is not None and sample.kernel_s["render"] == pytest.approx(0.008)
    # Without kernel frames there is no kernel time.
    walls = [f for f in frames() if f.kind == "wall"]
    assert sample_of(Probe(8), walls, {"render": 64.0, "other": 64.0}).kernel_s is None


def test_stored_frame_times_are_the_wall_frames_of_every_seed():
    run = SimpleNamespace(seed_results=[
        SimpleNamespace(seed=seed, timings={"frames_detail": [f.to_json()
                                                              for f in frames(seed)]})
        for seed in (1, 0)])
    samples, parts = stored_frame_times(run)
    assert samples == pytest.approx([0.010, 0.011, 0.012, 0.013, 0.011, 0.012, 0.013, 0.014])
    assert len(parts) == len(samples) and all(set(p) == {"render"} for p in parts)
