"""The timing protocol: stages, kernel time, the median frame, pooled seeds, machine load."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from renderers.timing import AFTER_KERNEL, FrameTime, Warmup, breakdown, pooled, summarize


def frame(stages: dict[str, float], whole: float, kernel: dict[str, float] | None = None):
    return FrameTime(stages=stages, whole_s=whole, kernel_s=kernel,
                     launches=None if kernel is None else dict.fromkeys(kernel, 2))


def test_the_summary_excludes_the_warmup_and_takes_the_median_frame():
    frames = [frame({"render": 0.010}, 0.011), frame({"render": 0.012}, 0.013),
              frame({"render": 0.011}, 0.012), frame({"render": 0.030}, 0.031)]
    summary = summarize(frames, Warmup(2.5, compile_s=1.9))
    # Lower median of 10, 11, 12, 30 ms: a frame that was measured.
    assert summary["frame_median_s"] == pytest.approx(0.011)
    assert summary["frame_mean_s"] == pytest.approx(0.01575)
    assert summary["warmup_s"] == 2.5 and summary["compile_s"] == 1.9
    assert summary["compile_s_estimate"] == pytest.approx(2.5 - 0.011)
    assert summary["device_time"] is None   # no kernel history
    assert "sync" in summary["protocol"] and "kernel history" in summary["protocol"]


def wall(stages: dict[str, float], whole: float):
    return frame(stages, whole)


def test_wall_statistics_come_from_wall_frames_and_kernel_statistics_from_kernel_frames():
    """Interleaved frames: the frame time, stages and breakdown from the frames timed
    without the kernel history, the kernel and harness parts from the median kernel frame
    (its harness its own wall - kernel time), and the frames after a kernel frame in
    neither. The kernel and after-kernel frames' wall
    times are made larger (the history's cost), so that a statistic over the wrong frames
    (or over all) gives another value."""
    walls = [wall({"training": 0.2, "render": 0.1, "training_paths": 0.01, "denoise": 0.02},
                  0.34),
             wall({"training": 0.3, "render": 0.1, "training_paths": 0.01, "denoise": 0.02},
                  0.45),
             wall({"training": 0.2, "render": 0.2, "training_paths": 0.02, "denoise": 0.02},
                  0.46)]
    kernels = [frame({"training": 0.5, "render": 0.3, "training_paths": 0.05, "denoise": 0.1},
                     1.0, {"training": 0.15, "render": 0.09, "training_paths": 0.0,
                           "denoise": 0.01, "other": 0.005}),
               frame({"training": 0.6, "render": 0.3, "training_paths": 0.05, "denoise": 0.1},
                     1.1, {"training": 0.2, "render": 0.08, "training_paths": 0.0,
                           "denoise": 0.01, "other": 0.0}),
               frame({"training": 0.7, "render": 0.3, "training_paths": 0.05, "denoise": 0.1},
                     1.2, {"training": 0.1, "render": 0.15, "training_paths": 0.01,
                           "denoise": 0.01, "other": 0.0})]
    after = [FrameTime(stages={"training": 0.9, "render": 0.5}, whole_s=1.5,
                       kind=AFTER_KERNEL)] * 3
    frames = [walls[0], kernels[0], after[0], walls[1], kernels[1], after[1], walls[2],
              kernels[2], after[2]]
    result = breakdown(frames)
    parts = result["parts_s"]
    assert list(parts) == ["render", "training_paths", "training", "denoise", "other"]
    # The median wall frame by stage total (0.33, 0.43, 0.44) is the second.
    assert parts == pytest.approx({"render": 0.1, "training_paths": 0.01, "training": 0.3,
                                   "denoise": 0.02, "other": 0.02})
    assert sum(parts.values()) == pytest.approx(result["frame_s"]) == pytest.approx(0.45)
    # The median kernel frame by kernel total (0.255, 0.29, 0.27) is the third.
    assert result["frame_kernel_s"] == pytest.approx(0.27)
    assert result["kernel_parts_s"]["render"] == pytest.approx(0.15)
    assert result["harness_parts_s"]["training"] == pytest.approx(0.7 - 0.1)
    assert result["kernel_frame_s"] == pytest.approx(1.2)
    assert result["harness_share"] == pytest.approx(1 - 0.27 / 1.2)
    assert result["inference_in_render"] is True
    summary = summarize(frames, Warmup())
    assert summary["frames"] == 9
    assert summary["frame_kinds"] == {"wall": 3, "kernel": 3, "after-kernel": 3}
    assert summary["frame_median_s"] == pytest.approx(0.43)
    assert summary["frame_mean_s"] == pytest.approx((0.33 + 0.43 + 0.44) / 3)
    device = summary["device_time"]
    assert device["wall_median_s"] == pytest.approx(0.45)
    assert device["kernel_median_s"] == pytest.approx(0.27)
    # Kernel frames' harness 0.745, 0.81, 0.93 s, shares 0.745, 0.736, 0.775.
    assert device["harness_median_s"] == pytest.approx(1.1 - 0.29)
    assert device["harness_share"] == pytest.approx(1 - 0.255 / 1.0)
    training = summary["stages"]["training"]
    assert training["median_s"] == pytest.approx(0.2) and training["min_s"] == 0.2
    assert training["kernel_median_s"] == pytest.approx(0.15)
    assert training["harness_median_s"] == pytest.approx(0.6 - 0.2)   # of 0.35, 0.4, 0.6
    assert training["launches_median"] == 2
    assert [d["kind"] for d in summary["frames_detail"]] == ["wall", "kernel",
                                                             "after-kernel"] * 3


def test_without_wall_frames_both_clocks_come_from_every_frame():
    """Runs stored before the frames were interleaved (every frame with the history on,
    no 'kind' stored) keep their statistics: the breakdown is one frame's, both clocks."""
    frames = [frame({"render": 0.1}, 0.12, {"render": 0.05, "other": 0.0}),
              frame({"render": 0.2}, 0.22, {"render": 0.08, "other": 0.0}),
              frame({"render": 0.3}, 0.32, {"render": 0.02, "other": 0.0})]
    stored = [{k: v for k, v in f.to_json().items() if k != "kind"} for f in frames]
    run = pooled([{"frames_detail": stored, "warmup_s": 1.0}])
    assert run["frame_median_s"] == pytest.approx(0.2)
    assert run["frame_kinds"] == {"wall": 0, "kernel": 3, "after-kernel": 0}
    assert run["breakdown"]["frame_kernel_s"] == pytest.approx(0.08)   # the same frame's
    only_wall = summarize([wall({"render": 0.1}, 0.12)], Warmup())
    assert only_wall["device_time"] is None and "kernel_parts_s" not in only_wall["breakdown"]


def test_pooled_seeds_report_stages_and_frame_time_from_one_statistic():
    """A slow first seed must not make a stage's time exceed the frame time: before, the
    stages were seed 0's and the frame time the median over seeds (39.8 vs 31.3 ms)."""
    slow = summarize([frame({"render": 0.040, "training": 0.002}, 0.043)] * 3, Warmup(1.0))
    fast = [summarize([frame({"render": 0.029, "training": 0.002}, 0.032)] * 3, Warmup(1.0))
            for _ in range(2)]
    run = pooled([slow, *fast])
    assert run["frames"] == 9
    for stage in run["stages"].values():
        assert stage["median_s"] <= run["frame_median_s"]
    stages = {k: v for k, v in run["breakdown"]["parts_s"].items() if k != "other"}
    assert sum(stages.values()) == pytest.approx(run["frame_median_s"]) == pytest.approx(0.031)
    assert run["warmup_s"] == 1.0 and "frames_detail" not in run


def test_a_nested_stage_is_not_counted_in_the_outer_one(mi):
    """The deferred cache inference runs inside mi.render: 'render' excludes it."""
    from renderers.timing import StageTimer

    timer = StageTimer()
    with timer.stage("render"):
        time.sleep(0.02)
        with timer.stage("inference"):
            time.sleep(0.05)
    assert timer.seconds["inference"] >= 0.05
    assert 0.02 <= timer.seconds["render"] < 0.05


@pytest.fixture(scope="module")
def pt_render(mi):
    from renderers.methods import get_method, parse_params
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 16)

    def render(frames: int):
        return get_method("pt").render(scene, parse_params("pt", {}), seed_parts=("timing",),
                                       spp=4, frames=frames)
    return render


def test_kernel_time_is_captured_and_bounded_by_wall_time(mi, pt_render):
    import drjit as dr

    before = dr.flag(dr.JitFlag.KernelHistory)
    out = pt_render(4)
    assert dr.flag(dr.JitFlag.KernelHistory) == before   # the loop restores the flag
    timed = [FrameTime.from_json(detail) for detail in out.timings["frames_detail"]]
    assert [f.kind for f in timed] == ["wall", "kernel", "after-kernel", "wall"]
    for frame_time in timed:
        if frame_time.kind != "kernel":
            assert frame_time.kernel_s is None and frame_time.readout_s == 0
            continue
        kernel = frame_time.kernel_parts()
        assert kernel is not None and kernel["render"] > 0
        assert frame_time.launches["render"] >= 1
        assert frame_time.kernel_total_s <= frame_time.whole_s
        assert frame_time.readout_s > 0   # reading the history: timed, kept out of the frame
        for name, seconds in frame_time.parts().items():
            assert kernel[name] <= seconds + 1e-4, name   # 0.1 ms: clock granularity
    device = out.timings["device_time"]
    assert device["kernel_median_s"] > 0 and device["wall_median_s"] > 0
    assert device["harness_share"] < 1 and device["launches_median"] >= 1
    assert out.timings["compile_s"] is not None and out.timings["compile_s"] >= 0


def _burners(count: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def test_a_cpu_burning_process_flags_the_timing(pt_render):
    """A render beside one CPU-bound process per core is flagged loaded, with the reason."""
    from renderers.load import STALL_LIMIT, usable_cores

    burners = _burners(usable_cores())
    try:
        time.sleep(0.3)
        loaded = pt_render(200).timings["load"]
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()
    assert loaded["loaded"] is True, loaded
    assert loaded["reasons"] and "other work" in loaded["reasons"][0]
    if loaded["cpu_stall_fraction"] is not None:
        assert loaded["cpu_stall_fraction"] > STALL_LIMIT


def test_a_render_on_a_quiet_machine_is_not_flagged(pt_render, monkeypatch, tmp_path):
    """The same render, the kernel reporting no CPU stall over it (a pressure file whose
    counter does not move: a machine where nothing else runs), is not flagged, and the
    window's stall is 0. On a shared machine the real counter cannot be held still, so the
    kernel's report is the one thing replaced; the monitor and the frame loop are the
    render's own."""
    import renderers.load as load

    pressure = tmp_path / "cpu"
    pressure.write_text("some avg10=0.00 avg60=0.00 avg300=0.00 total=123456\n"
                        "full avg10=0.00 avg60=0.00 avg300=0.00 total=0\n")
    monkeypatch.setattr(load, "PRESSURE_FILE", pressure)
    quiet = pt_render(200).timings["load"]
    assert quiet["loaded"] is False and quiet["reasons"] == [], quiet
    assert quiet["cpu_stall_fraction"] == 0.0 and quiet["basis"] == "cpu pressure"


def test_the_load_verdict_falls_back_to_the_cpu_share_and_says_when_it_cannot_tell():
    from renderers.load import judge

    assert judge(0.5, 0.99)["loaded"] is True           # pressure wins
    assert judge(0.01, 0.2)["loaded"] is False
    assert judge(None, 0.5) == {"loaded": True, "basis": "process cpu share",
                                "reasons": [judge(None, 0.5)["reasons"][0]]}
    assert judge(None, 0.95)["loaded"] is False
    unknown = judge(None, None)
    assert unknown["loaded"] is None and "unknown" in unknown["reasons"][0]
    # A share of the window is at most all of it: the kernel's stall counter, advanced
    # in steps, once read 7.73 windows over a short one ('773 % of the time').
    assert "waited for a core 50 % of the time" in judge(0.5, None)["reasons"][0]
    assert "waited for a core all of the time" in judge(7.73, None)["reasons"][0]
