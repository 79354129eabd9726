"""Wall frames and kernel frames (renderers.timing.frame_kind): the frame loop times
the frame with Dr.Jit's kernel history off and reads kernel times from interleaved
frames with it on; the warm-up settles a frozen function's recordings in both states;
the images do not depend on which frames record the history."""

from __future__ import annotations

import numpy as np
import pytest

import renderers.methods.base as base
from renderers import timing
from renderers.methods.base import FrameHooks, run_frames
from renderers.timing import KERNEL, KERNEL_EVERY, frame_kind, kernel_history_enabled

FRAMES = 5


class FlagSeen:
    """A frame function around one frozen Dr.Jit function (keyed on the JIT flags, the
    kernel history's included, as every frozen call is): notes the kernel-history flag
    of each call by frame index (-1: the warm-up)."""

    def __init__(self) -> None:
        import drjit as dr
        from drjit.llvm import Float, UInt32

        self.float, self.uint = Float, UInt32
        self.fn = dr.freeze(lambda x, seed: x * 2 + seed)
        self.calls: list[tuple[int, bool]] = []

    def __call__(self, index: int, seed: int, timer: timing.StageTimer) -> np.ndarray:
        self.calls.append((index, kernel_history_enabled()))
        with timer.stage("render"):
            value = self.fn(self.float(1.0, 2.0, 3.0, 4.0), self.uint(seed % 1000))
            timing.synchronize(value)
        return np.broadcast_to(value.numpy().reshape(2, 2, 1), (2, 2, 3))

    def recordings(self) -> int:
        return int(self.fn.n_recordings)


def run(frame: FlagSeen):
    return run_frames(frame, seed_parts=("kernel-frames",), frames=FRAMES, spp=1, aov_names=())


def flag_problems(frame: FlagSeen, output) -> list[str]:
    """Where the flag a timed frame ran under is not its kind's, or not the schedule's."""
    seen = [on for index, on in frame.calls if index >= 0]
    kinds = [detail["kind"] for detail in output.timings["frames_detail"]]
    problems = []
    if seen != [frame_kind(index) == KERNEL for index in range(FRAMES)]:
        problems.append(f"flags {seen} are not the schedule's")
    if [kind == KERNEL for kind in kinds] != seen:
        problems.append(f"kinds {kinds} do not match the flags {seen}")
    return problems


def test_wall_frames_run_without_the_history_and_kernel_frames_with_it(mi, monkeypatch):
    frame = FlagSeen()
    output = run(frame)
    assert flag_problems(frame, output) == []
    assert output.timings["frame_kinds"] == {"wall": 3, "kernel": 1, "after-kernel": 1}
    assert output.timings["device_time"]["kernel_median_s"] > 0
    # Planted: a loop that leaves the history on in every frame.
    monkeypatch.setattr(base, "kernel_history", lambda on=True: timing.kernel_history(True))
    planted = FlagSeen()
    assert flag_problems(planted, run(planted))


def test_recordings_settle_in_the_warm_up_in_both_states(mi, monkeypatch):
    frame = FlagSeen()
    record = run(frame).timings["frozen"]
    assert {on for index, on in frame.calls if index < 0} == {True, False}
    assert record["recordings_after_frames"] == record["recordings_after_warmup"] >= 2
    # Planted: a warm-up that settles the history-on state alone.
    monkeypatch.setattr(base, "history_states", lambda _every: (True,))
    planted = run(FlagSeen()).timings["frozen"]
    assert planted["recordings_after_frames"] > planted["recordings_after_warmup"]


@pytest.fixture(scope="module")
def pt_frames(mi):
    from renderers.methods import get_method, parse_params
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 8)
    method, params = get_method("pt"), parse_params("pt", {"max_depth": 3})

    def render(kernel_every: int):
        return method.render(scene, params, seed_parts=("kernel-frames", "pt"), spp=1,
                             frames=4, hooks=FrameHooks(keep_frames=True,
                                                        kernel_every=kernel_every))
    return render


def test_the_images_are_those_of_the_history_in_every_frame(pt_frames, monkeypatch):
    """The previous protocol recorded the history in every frame (kernel_every 1): the
    same seeds give bit-identical frames with the frames interleaved."""
    before, after = pt_frames(1), pt_frames(KERNEL_EVERY)
    for a, b in zip(before.frames, after.frames, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(before.accumulated, after.accumulated)
    # Planted: kernel frames rendered with another seed.
    derive = base.derive_seed
    monkeypatch.setattr(base, "derive_seed", lambda *parts: derive(*parts) + (
        kernel_history_enabled() and isinstance(parts[-1], int) and parts[-1] >= 0))
    assert not np.array_equal(pt_frames(KERNEL_EVERY).accumulated, before.accumulated)


def test_one_frame_seeds_continue_the_schedule_so_the_run_has_kernel_times(mi):
    """A run of one frame per seed (the default render) gets its kernel frames from the
    seeds after the first: each seed starts where the last left off (first_frame)."""
    def seeds(first_frames: list[int]) -> dict:
        outputs = [run_frames(FlagSeen(), seed_parts=("kernel-frames", k), frames=1, spp=1,
                              aov_names=(), hooks=FrameHooks(first_frame=first))
                   for k, first in enumerate(first_frames)]
        return timing.pooled([output.timings for output in outputs])

    run_timings = seeds([0, 1, 2, 3])
    assert run_timings["frame_kinds"] == {"wall": 2, "kernel": 1, "after-kernel": 1}
    assert run_timings["device_time"]["kernel_median_s"] > 0
    # Planted: every seed starting the schedule afresh leaves the run no kernel frame.
    assert seeds([0, 0, 0, 0])["frame_kinds"]["kernel"] == 0


class Unequal:
    """A frame function whose frames are unequal, as `grid-cache`'s are (a frame that
    records its propagation pass anew, a cache whose work changes from frame to frame):
    its kernel frames launch ~30000x the work of its other frames."""

    def __call__(self, index: int, _seed: int, timer: timing.StageTimer) -> np.ndarray:
        import drjit as dr
        from drjit.llvm import Float

        heavy = index >= 0 and frame_kind(index) == KERNEL
        with timer.stage("render"):
            x = dr.arange(Float, 1 << 21 if heavy else 64)
            total = dr.sum(dr.sin(x) * dr.cos(x))
            timing.synchronize(total)
        return np.zeros((2, 2, 3))


def test_the_harness_is_of_the_frames_that_read_both_clocks(mi):
    """The harness of a run whose frames differ is each kernel frame's wall time less its
    own kernel time, never negative; taken as the wall frames' median less the kernel
    frames' (the computation before), it reads negative here, as `grid-cache`'s did
    (-2.96 ms at 128x128)."""
    timings = run_frames(Unequal(), seed_parts=("kernel-frames", "unequal"), frames=8,
                         spp=1, aov_names=()).timings
    device, stage = timings["device_time"], timings["stages"]["render"]
    assert device["harness_median_s"] >= 0 and 0 <= device["harness_share"] < 1
    assert stage["harness_median_s"] >= 0
    assert min(timings["breakdown"]["harness_parts_s"].values()) >= 0
    assert 0 <= timings["breakdown"]["harness_share"] < 1
    # Planted: the wall frames' median less the kernel frames' median.
    assert device["wall_median_s"] - device["kernel_median_s"] < 0
    assert stage["median_s"] - stage["kernel_median_s"] < 0
