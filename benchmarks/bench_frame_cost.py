"""Benchmark: what a frame costs, and where its fixed cost goes (docs/timing.md).

Four tables, each measured in this one run with interleaved rounds and medians:

1. **Frame time at 8², 64², 128²** per method: wall ms per frame (the stage total
   of the median wall frame, timed with Dr.Jit's kernel history off), kernel ms (of
   the median kernel frame, interleaved with them, history on), the harness share
   (that kernel frame's wall time outside its own kernels: never another frame's, whose
   work may differ; it includes recording the history) and kernel launches per frame;
   Mitsuba's own ``path`` through ``mi.render`` (plain and frozen, handed the scene's
   arrays as every frozen call of the project is: renderers.frozen.Frozen) as the
   reference, and Mitsuba's
   ``depth`` (one camera ray per pixel) frozen on each scene of the rows: the least a
   frozen call that reads that scene costs (Dr.Jit walks every variable of the scene's
   objects on each call: docs/timing.md, "The floor of a frozen call").
2. **The fixed cost at 8²**: the median kernel frame split into harness (its wall -
   kernel time of every part), the method's own fixed work (kernel time of stages whose
   size does not grow with the image: training at its record floor, the visibility
   caches' training points) and pixel work (kernel time of the stages that grow with
   pixels x spp).
3. **The per-stage cost model** a + b x size of each method, fitted at 64², 128²,
   256² (and the caches' floors scaled x4, x16) with 95 % intervals, and its
   projection to 1920x1080 on this device.
4. **What recording the kernel history costs**: every row's median frame with it on
   in every frame and off in every frame, interleaved (a replay copies each kernel's
   source into the history), beside the frame time the protocol reports (its wall
   frames, history off, interleaved with its kernel frames): the evidence that the
   reported frame time is the frame's without the history.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from statistics import median
from typing import Any

from renderers.backend import device_info, init_backend
from renderers.timing import KERNEL_EVERY

#: (label, method, scene, params) of each row (spp 1).
CASES: tuple[tuple[str, str, str, dict[str, Any]], ...] = (
    ("pt (door)", "pt", "door", {}),
    ("nirc biased N_c 4 (door)", "nirc", "door", {"estimator": "biased", "nc": [4]}),
    ("nrc (door)", "nrc", "door", {}),
    ("restir-di d2 (many-lights)", "restir-di", "many-lights", {"max_depth": 2}),
    ("nvc-lights d2 (many-lights)", "nvc-lights", "many-lights", {"max_depth": 2}),
    ("pt d2 (many-lights)", "pt", "many-lights", {"max_depth": 2}),
    ("pt-power d2 (many-lights)", "pt-power", "many-lights", {"max_depth": 2}),
    ("nvc-env (sky)", "nvc-env", "sky", {}),
    ("nrc-di (many-lights)", "nrc-di", "many-lights", {}),
    ("grid-cache (many-lights)", "grid-cache", "many-lights", {"prefill_frames": 8}),
)

#: The goals of a steady-state frame (docs/timing.md, "Goals"): for these rows, the
#: harness share of the median frame at most this at that resolution ...
HARNESS_GOALS = {128: 0.10, 8: 0.25}
GOAL_ROWS = {128: tuple(label for label, *_ in CASES),
             8: ("pt (door)", "nirc biased N_c 4 (door)", "nrc (door)",
                 "restir-di d2 (many-lights)", "nvc-lights d2 (many-lights)")}
#: ... and `restir-di`'s frame at 8x8 at most this fraction of its frame at 128x128 (its
#: fixed cost against its pixel work; `pt`'s is ~0.02) ...
RESTIR_ROW = "restir-di d2 (many-lights)"
RESTIR_SMALL_OVER_LARGE = 0.15
#: ... and `pt`'s 8x8 frame at most this many times Mitsuba's frozen `path`'s.
PT_OVER_FROZEN_PATH = 1.5
#: ... and `restir-di`'s per-pixel cost b at most this many times `pt-power`'s (table 3).
RESTIR_OVER_PT_POWER = 4.0
#: The floor row of each goal row's scene (a frozen call that reads the scene).
FLOOR_ROWS = {"door": "depth (Mitsuba, frozen, door)",
              "many-lights": "depth (Mitsuba, frozen, many-lights)"}


class Scenes:
    """The scene a probe renders, and no other alive (cost_model.SceneSlot)."""

    def __init__(self) -> None:
        from jobs.costs.cost_model import SceneSlot
        from renderers.scenes import load_scene

        self.slot = SceneSlot(lambda key: load_scene(*key))

    def __call__(self, name: str, res: int) -> Any:
        return self.slot((name, res))


def method_timings(scenes: Scenes, method: str, scene: str, params: Any, res: int,
                   frames: int, kernel_every: int = KERNEL_EVERY) -> dict[str, Any]:
    """One seed's timings (renderers.timing.summarize), no pre-training; every
    ``kernel_every``-th frame a kernel frame (renderers.methods.base.FrameHooks)."""
    from renderers.methods import get_method
    from renderers.methods.base import FrameHooks

    if "pretrain_frames" in type(params).model_fields:
        params = params.model_copy(update={"pretrain_frames": 0})
    return get_method(method).render(
        scenes(scene, res), params, seed_parts=("bench-frame-cost", method, res), spp=1,
        frames=frames, hooks=FrameHooks(kernel_every=kernel_every)).timings


#: Rows of Mitsuba's own integrators: label -> (integrator, scene, frozen).
MITSUBA_ROWS: dict[str, tuple[str, str, bool]] = {
    "path (Mitsuba)": ("path", "door", False),
    "path (Mitsuba, frozen)": ("path", "door", True),
    "depth (Mitsuba, frozen, door)": ("depth", "door", True),
    "depth (Mitsuba, frozen, many-lights)": ("depth", "many-lights", True),
}


def mitsuba_render(mi: Any, scenes: Scenes, row: str, res: int, frames: int,
                   kernel_every: int = KERNEL_EVERY) -> dict[str, Any]:
    """A :data:`MITSUBA_ROWS` row at 1 spp through ``mi.render`` (or a frozen function of
    it), timed as 'render' by the methods' frame loop (renderers.methods.base.run_frames:
    its warm-up, wall and kernel frames)."""
    from renderers.frozen import Frozen
    from renderers.methods.base import FrameHooks, run_frames
    from renderers.timing import StageTimer, synchronize

    integrator_type, scene_name, frozen = MITSUBA_ROWS[row]
    scene = scenes(scene_name, res).scene
    integrator = mi.load_dict({"type": integrator_type})

    def render(scene: Any, seed: Any) -> Any:
        return mi.render(scene, integrator=integrator, spp=1, seed=seed)

    call = Frozen(render) if frozen else render
    seed_type = mi.UInt32 if frozen else int

    def frame(_index: int, seed: int, timer: StageTimer) -> Any:
        with timer.stage("render"):
            image = call(scene, seed_type(seed))
            synchronize(image)
        return image

    if isinstance(call, Frozen):   # warmed up until its recordings settle
        frame.recordings = call.recordings  # type: ignore[attr-defined]
    return run_frames(frame, seed_parts=("bench-frame-cost", row, res), frames=frames, spp=1,
                      aov_names=(), hooks=FrameHooks(kernel_every=kernel_every)).timings


def frame_row(timings: dict[str, Any]) -> tuple[float, float, float, float, float]:
    """(ms per frame: the median wall frame; kernel ms, harness ms and harness share: the
    median kernel frame's, both clocks of that one frame; launches per frame)."""
    frame = timings["breakdown"]
    kernel = frame["frame_kernel_s"]
    launches = sum(stage.get("launches_median", 0) for stage in timings["stages"].values())
    return (1e3 * timings["frame_median_s"], 1e3 * kernel,
            1e3 * sum(frame["harness_parts_s"].values()), frame["harness_share"], launches)


def rounds_of(configs: list[Any], measure: Callable[[Any], Any], rounds: int) -> dict[Any, list]:
    from jobs.protocol.calibration import interleaved_rounds

    return interleaved_rounds(configs, measure, rounds, name=str).times


def frame_table(mi: Any, scenes: Scenes, cases: tuple[tuple, ...], params: dict[str, Any],
                resolutions: list[int],
                frames: int, rounds: int) -> dict[tuple[str, int], dict[str, Any]]:
    """Table 1; returns the median round's timings per (row, resolution)."""
    rows = [label for label, *_ in cases] + list(MITSUBA_ROWS)
    configs = [(row, res) for res in resolutions for row in rows]
    scene_of = {label: (method, scene) for label, method, scene, _ in cases}

    def measure(config: tuple[str, int]) -> dict[str, Any]:
        row, res = config
        if row in MITSUBA_ROWS:
            return mitsuba_render(mi, scenes, row, res, frames)
        method, scene = scene_of[row]
        return method_timings(scenes, method, scene, params[row], res, frames)

    times = rounds_of(configs, measure, rounds)
    chosen = {c: sorted(t, key=lambda x: x["frame_median_s"])[(len(t) - 1) // 2]
              for c, t in times.items()}
    print(f"\n1. frame time (median of {rounds} interleaved rounds of {frames} frames; "
          "ms of the median wall frame; kernel and harness: the median kernel frame's, "
          "harness = its wall outside its kernels)")
    header = f"{'method':<38}" + "".join(f"{f'{r}x{r}: ms kernel harness launches':>42}"
                                         for r in resolutions)
    print(header)
    for row in rows:
        cells = []
        for res in resolutions:
            ms, kernel, _harness, share, launches = frame_row(chosen[row, res])
            cells.append(f"{ms:>12.3g}{kernel:>9.3g}{100 * share:>9.0f}%{launches:>11.0f}")
        print(f"{row:<38}" + "".join(f"{c:>42}" for c in cells))
    loaded = [f"{row} {res}" for (row, res), t in chosen.items() if (t.get("load") or {}).get("loaded")]
    print("loaded while timed: " + (", ".join(loaded) if loaded else "none"))
    goals(cases, chosen, resolutions)
    return chosen


def goals(cases: tuple, chosen: dict[tuple[str, int], dict[str, Any]],
          resolutions: list[int]) -> None:
    """The goals of :data:`HARNESS_GOALS` and :data:`PT_OVER_FROZEN_PATH` on table 1's
    median frames, each met or not, with the floor of a frozen call of the row's scene
    (its harness ms) beside the row's harness ms."""
    scene_of = {label: scene for label, _method, scene, _ in cases}
    print("\ngoals (table 1's median frames):")
    for res, limit in HARNESS_GOALS.items():
        if res not in resolutions:
            continue
        for row in (r for r in GOAL_ROWS[res] if r in scene_of):
            _ms, _kernel, harness, share, _ = frame_row(chosen[row, res])
            floor_row = FLOOR_ROWS.get(scene_of[row])
            floor = ""
            if floor_row is not None:
                floor = f"; floor of its scene {frame_row(chosen[floor_row, res])[2]:.3g} ms"
            verdict = "met" if share <= limit else "NOT met"
            print(f"  harness <= {100 * limit:.0f} % at {res}x{res}: {row:<30} "
                  f"{100 * share:5.1f} % ({harness:.3g} ms{floor})  {verdict}")
    if {8, 128} <= set(resolutions) and RESTIR_ROW in scene_of:
        ratio = frame_row(chosen[RESTIR_ROW, 8])[0] / frame_row(chosen[RESTIR_ROW, 128])[0]
        verdict = "met" if ratio <= RESTIR_SMALL_OVER_LARGE else "NOT met"
        print(f"  {RESTIR_ROW} 8x8 / 128x128 <= {RESTIR_SMALL_OVER_LARGE}: {ratio:.3f}  "
              f"{verdict}")
    if 8 in resolutions and "pt (door)" in scene_of:
        ratio = (frame_row(chosen["pt (door)", 8])[0]
                 / frame_row(chosen["path (Mitsuba, frozen)", 8])[0])
        verdict = "met" if ratio <= PT_OVER_FROZEN_PATH else "NOT met"
        print(f"  pt (door) 8x8 / Mitsuba's frozen path 8x8 <= {PT_OVER_FROZEN_PATH}: "
              f"{ratio:.2f}  {verdict}")


def fixed_cost_table(cases: tuple, chosen: dict[tuple[str, int], dict[str, Any]],
                     res: int) -> None:
    """Table 2: the median kernel frame at ``res`` split into harness, fixed work, pixel
    work (its own wall and kernel times: they add up to its wall time)."""
    from renderers.methods import get_method, parse_params

    print(f"\n2. where the frame goes at {res}x{res} (ms of the median kernel frame)")
    print(f"{'method':<30}{'frame':>9}{'harness':>16}{'fixed work':>16}{'pixel work':>16}")
    for label, method, _scene, params in cases:
        frame = chosen[label, res]["breakdown"]
        fixed_stages = set(get_method(method).stage_sizes(parse_params(method, params), 1, 1))
        kernel = frame["kernel_parts_s"]
        whole = frame["kernel_frame_s"]
        harness = sum(frame["harness_parts_s"].values())
        fixed = sum(kernel[n] for n in kernel if n in fixed_stages)
        pixel = sum(kernel[n] for n in kernel if n not in fixed_stages)

        def part(seconds: float, whole: float = whole) -> str:
            return f"{1e3 * seconds:.3g} ({100 * seconds / whole:.0f}%)"
        print(f"{label:<30}{1e3 * whole:>9.3g}{part(harness):>16}{part(fixed):>16}"
              f"{part(pixel):>16}")
    print("fixed work: kernel time of the stages whose size does not grow with the image "
          "(training at its record floor, visibility-cache training points)")


def cost_model_table(scenes: Scenes, cases: tuple, params: dict[str, Any], device_key: str,
                     resolutions: list[int], frames: int, rounds: int,
                     project: tuple[int, int]) -> None:
    """Table 3: a and b per stage with intervals, and the projection."""
    from jobs.costs import cost_model
    from renderers.methods import get_method

    print(f"\n3. per-stage cost model (fitted at {', '.join(f'{r}x{r}' for r in resolutions)}"
          f"; {rounds} interleaved rounds of {frames} frames; 95 % intervals)")
    models = {}
    for label, method, scene, _ in cases:
        model = models[label] = cost_model.measure(
            get_method(method), params[label], 1, device_key,
            lambda res, p, spp, method=method, scene=scene: method_timings(
                scenes, method, scene, p, res, frames),
            resolutions=resolutions, rounds=rounds)
        print(f"{label}")
        for name, stage in model.stages.items():
            wall = stage.wall
            slope = ("b -" if wall.slope is None else
                     f"b {1e9 * wall.slope:.3g} [{1e9 * wall.slope_ci[0]:.3g}, "
                     f"{1e9 * wall.slope_ci[1]:.3g}] ns/unit")
            print(f"   {name:<16} a {1e3 * wall.intercept:8.3g} ms [{1e3 * wall.intercept_ci[0]:.3g}, "
                  f"{1e3 * wall.intercept_ci[1]:.3g}]   {slope}   ({stage.unit})")
        projection = model.project(*project)
        if projection.frame_s is not None:
            lo, hi = projection.frame_ci
            print(f"   -> {project[0]}x{project[1]}: {1e3 * projection.frame_s:.4g} ms/frame "
                  f"[{1e3 * lo:.4g}, {1e3 * hi:.4g}], harness share "
                  f"{100 * (projection.harness_share or 0):.1f} % (projection from this device)")
        for note in projection.notes:
            print(f"      {note}")
    restir, power = (models.get(row) for row in ("restir-di d2 (many-lights)",
                                                   "pt-power d2 (many-lights)"))
    if restir is not None and power is not None:
        ratio = restir.stages["render"].wall.slope / power.stages["render"].wall.slope
        verdict = "met" if ratio <= RESTIR_OVER_PT_POWER else "NOT met"
        print(f"goal: restir-di's b / pt-power's b (render, max_depth 2) <= "
              f"{RESTIR_OVER_PT_POWER}: {ratio:.2f}  {verdict}")


#: Table 4's protocols: the kernel history in every frame, in none, and the one the
#: frame loop reports (wall frames interleaved with kernel frames).
HISTORY_PROTOCOLS = {"on": 1, "off": 0, "reported": KERNEL_EVERY}


def history_overhead(mi: Any, scenes: Scenes, cases: tuple, params: dict[str, Any],
                     res: int, frames: int, rounds: int) -> None:
    """Table 4: every row's median frame at ``res`` (its whole wall time: its stages and
    'other', less the reading of the history) with the kernel history on in every frame,
    off in every frame, and as the frame loop reports it (the median wall frame),
    interleaved."""
    rows = [label for label, *_ in cases] + list(MITSUBA_ROWS)
    configs = [(row, protocol) for row in rows for protocol in HISTORY_PROTOCOLS]
    scene_of = {label: (method, scene) for label, method, scene, _ in cases}

    def measure(config: tuple[str, str]) -> float:
        row, protocol = config
        every = HISTORY_PROTOCOLS[protocol]
        if row in MITSUBA_ROWS:
            timings = mitsuba_render(mi, scenes, row, res, frames, kernel_every=every)
        else:
            method, scene = scene_of[row]
            timings = method_timings(scenes, method, scene, params[row], res, frames,
                                     kernel_every=every)
        return timings["breakdown"]["frame_s"]

    times = rounds_of(configs, measure, rounds)
    print(f"\n4. kernel history's own cost at {res}x{res} (median of {rounds} interleaved "
          "rounds; ms of the median frame; reported: the wall frames of the frame loop)")
    for row in rows:
        on, off, reported = (median(times[row, protocol]) for protocol in HISTORY_PROTOCOLS)
        print(f"{row:<38} on {1e3 * on:8.3g}  off {1e3 * off:8.3g}  "
              f"on - off {1e3 * (on - off):7.3f}  on/off {on / off:.3f}  "
              f"reported {1e3 * reported:8.3g}  reported/off {reported / off:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", default="8,64,128", help="resolutions of table 1")
    parser.add_argument("--cost-res", default="64,128,256", help="resolutions of the model")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--project", default="1920x1080")
    parser.add_argument("--tables", default="1,2,3,4", help="which tables to print")
    parser.add_argument("--only", default="", help="rows whose label contains this text")
    args = parser.parse_args()
    cases = tuple(case for case in CASES if args.only in case[0])
    tables = set(args.tables.split(","))

    mi = init_backend()
    from renderers.methods import parse_params

    device_key = device_info()["device_key"]
    resolutions = [int(r) for r in args.res.split(",")]
    width, height = (int(n) for n in args.project.split("x"))
    params = {label: parse_params(method, p) for label, method, _, p in cases}
    scenes = Scenes()
    start = time.perf_counter()
    print(f"device: {device_key}")
    if tables & {"1", "2"}:
        chosen = frame_table(mi, scenes, cases, params, resolutions, args.frames, args.rounds)
        fixed_cost_table(cases, chosen, min(resolutions))
    if "3" in tables:
        cost_model_table(scenes, cases, params, device_key, [int(r) for r in args.cost_res.split(",")],
                         args.frames, args.rounds, (width, height))
    if "4" in tables:
        history_overhead(mi, scenes, cases, params, min(resolutions), max(args.frames, 8),
                         args.rounds + 2)
    print(f"\n({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
