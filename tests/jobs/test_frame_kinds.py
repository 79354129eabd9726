"""Readers of stored frames take wall times from wall frames and kernel times from kernel
frames (renderers.timing.frame_kind): the cost model's probe samples and pareto's stored
frame times. The kernel and after-kernel frames below are slower (the history's cost),
so a reader that took every frame would read another value."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from jobs.costs.cost_model import PIXEL_UNIT, Probe, fit_model, sample_of
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
    # Harness: each kernel frame's own wall less its own kernels (30 - 8 and 30 - 9 ms,
    # lower median 21), never a wall frame's wall less a kernel frame's kernels (11 - 8).
    assert sample.harness_s is not None and sample.harness_s["render"] == pytest.approx(0.021)
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


def test_a_projected_harness_share_is_of_the_kernel_frames_alone():
    """Kernel frames that do far more work than wall frames (grid-cache's wider passes):
    kernels of 300 ms in frames of 330 ms beside wall frames of 10-13 ms. The share is
    the kernel frames' own 30 / 330 ms; a wall frame's time less a kernel frame's
    kernels would read below 0 (11 - 300 ms)."""
    def heavy(size: float) -> list[FrameTime]:
        def wall(ms: float) -> FrameTime:
            return FrameTime(stages={"render": 1e-3 * ms * size}, whole_s=1e-3 * ms * size)

        kernel = FrameTime(stages={"render": 0.330 * size}, whole_s=0.330 * size,
                           kernel_s={"render": 0.300 * size, "other": 0.0})
        return [wall(10), kernel, wall(11), wall(12), kernel, wall(13)]

    samples = [sample_of(Probe(n), heavy(n / 8), {"render": n * n, "other": n * n})
               for n in (8, 16, 32)]
    model = fit_model("test", 1, "test-device", samples, lambda pixels: {
        "render": float(pixels), "other": float(pixels)}, {"render": PIXEL_UNIT})
    projection = model.project(64, 64)
    assert projection.harness_share == pytest.approx(30 / 330, rel=1e-6)
    wall_less_kernel = projection.frame_s + projection.other_s - projection.kernel_s
    assert wall_less_kernel < 0                     # what the share is not taken from
