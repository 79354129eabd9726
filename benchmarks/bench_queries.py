"""Benchmark: what the cache queries cost a NIRC frame, next to PT.

Prints, for one 1-spp frame on one scene, the median over ``--repeats`` of
the frame time (``mi.render``: path tracing + cache inference) of

- PT 1 spp (the reference of every ratio),
- biased NIRC (BTH) for N_c = 1, 2, 4, 8,
- adaptive NIRC with an empty v1 mask (no pixel terminates into the cache at
  v1; later vertices by the spread heuristic),
- the same with the spread heuristic off (``sph_c`` 1e6): no lane uses the
  cache, so no query is evaluated: the goal is <= 1.1x PT,

split, where the integrator defers its queries (renderers/integrators/
deferred.py), into the stages ``render`` (path tracing, recording the cache
vertices) and ``inference`` (the deferred pass: re-creating the recorded
vertices, drawing NIRC's N_c directions, the network), with the cache queries
evaluated per frame. All measured in this run, interleaved (every repeat renders each
configuration once, so a change in the shared machine's load hits all alike),
warm-up excluded, device synchronised before each clock read.

Second part: the deferred pass on Q = V * N_c queries at V shading points with
the per-surface features (hash grid + first-layer surface columns, NIRC Sec.
4.5) recomputed per query (what deferred.py does) or computed once per point
and gathered per query.

Runs on older code too (then ``render`` is the whole frame and the query
count is not known), to compare before and after a change.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from statistics import median
from typing import Any

from renderers.backend import device_info, init_backend


def configurations() -> list[tuple[str, dict[str, Any] | None, bool]]:
    """(label, nirc parameters or None for PT, empty v1 mask)."""
    biased = [(f"NIRC biased BTH N_c={nc}", {"estimator": "biased", "nc": [nc]}, False)
              for nc in (1, 2, 4, 8)]
    adaptive = ("NIRC adaptive, empty mask", {"estimator": "biased", "termination": "adaptive"},
                True)
    # sph_c = 1e6: the spread heuristic never stops a path, so no lane uses the cache.
    unused = ("NIRC adaptive, no cache use", {"estimator": "biased", "termination": "adaptive",
                                              "sph_c": 1e6}, True)
    return [("PT 1 spp", None, False), *biased, adaptive, unused]


def build_integrators(mi, scene, train_frames: int) -> dict[str, Any]:
    """The loaded, briefly trained integrators of every configuration."""
    import numpy as np

    from renderers.methods import nirc as nirc_method
    from renderers.methods import parse_params
    from renderers.methods.budget import frame_training_budget
    from renderers.methods.cached import train_once
    from renderers.methods.pt import path_integrator
    from renderers.timing import StageTimer

    integrators = {}
    for label, params, empty_mask in configurations():
        if params is None:
            integrators[label] = path_integrator(parse_params("pt", {}))
            continue
        nirc_params = parse_params("nirc", params)
        integrator, trainer, cache = nirc_method.build(scene, nirc_params, 1)
        budget = frame_training_budget(int(np.prod(scene.resolution)), nirc_params, cache.config)
        for frame in range(train_frames):  # so that the cache is not all zeros
            train_once(cache, trainer, scene, budget, seed=frame, timer=StageTimer())
        integrator.cache = cache
        if empty_mask:
            width, height = scene.resolution
            integrator.set_v1_mask(np.zeros((height, width), bool))
        integrators[label] = integrator
    return integrators


def render_once(mi, scene, integrator, seed: int) -> dict[str, float]:
    """One timed 1-spp frame: its stages, its total and the cache queries evaluated."""
    from renderers.timing import StageTimer, synchronize

    timer = StageTimer()
    if hasattr(integrator, "timer"):
        integrator.timer = timer
        integrator.query_counts.clear()
    start = time.perf_counter()
    with timer.stage("render"):
        image = mi.render(scene.scene, integrator=integrator, spp=1, seed=seed)
        synchronize(image)
    result = {"total": time.perf_counter() - start, **timer.seconds}
    if hasattr(integrator, "query_counts"):
        result["queries"] = sum(c.queries for c in integrator.query_counts)
    return result


def frame_table(mi, scene, integrators: dict[str, Any], repeats: int) -> None:
    samples: dict[str, list[dict[str, float]]] = {label: [] for label in integrators}
    for integrator in integrators.values():   # warm-up: JIT compilation
        render_once(mi, scene, integrator, seed=10_000)
    for repeat in range(repeats):
        for label, integrator in integrators.items():
            samples[label].append(render_once(mi, scene, integrator, seed=repeat))

    def med(label: str, key: str) -> float:
        return median(s.get(key, 0.0) for s in samples[label])

    pt = med("PT 1 spp", "total")
    print(f"{'configuration':<28}{'frame ms':>10}{'x PT':>7}{'render ms':>11}{'x PT':>7}"
          f"{'inference ms':>14}{'queries':>10}")
    for label in integrators:
        total, render = med(label, "total"), med(label, "render")
        queries = f"{med(label, 'queries'):.0f}" if "queries" in samples[label][0] else "-"
        print(f"{label:<28}{1e3 * total:>10.2f}{total / pt:>7.2f}{1e3 * render:>11.2f}"
              f"{render / pt:>7.2f}{1e3 * med(label, 'inference'):>14.2f}{queries:>10}")


def sharing_variants(mi, dr, cache: Any, points: int, nc: int) -> dict[str, Callable[[], Any]]:
    """The deferred pass on ``points`` shading points with ``nc`` queries each, with the
    per-surface features recomputed per query or computed per point and gathered."""
    from benchmarks.bench_cache import _inputs

    values = _inputs(mi, dr, points * nc, seed=nc)
    direction = values.pop("direction")
    vertex = dr.arange(mi.UInt32, points * nc) // nc
    surface_in = {k: dr.gather(type(v), v, dr.arange(mi.UInt32, points) * nc)
                  for k, v in values.items()}
    dr.eval(vertex, surface_in)

    def recompute() -> Any:
        inputs = {k: dr.gather(type(v), v, vertex) for k, v in surface_in.items()}
        return cache.query(cache.surface_features(**inputs), direction)

    def shared() -> Any:
        rows = cache.surface_features(**surface_in)
        dr.eval(rows)
        return cache.query([dr.gather(type(r), r, vertex) for r in rows], direction)

    return {"recompute": recompute, "shared": shared}


def surface_sharing(mi, scene, points: int, repeats: int) -> None:
    """The deferred pass with per-surface features recomputed per query vs gathered."""
    import drjit as dr

    from benchmarks.bench_cache import timed_interleaved
    from renderers.methods import nirc as nirc_method
    from renderers.methods import parse_params

    _, _, cache = nirc_method.build(scene, parse_params("nirc", {}), 1)
    print(f"\ndeferred pass, {points} shading points, ms (median of {repeats}, interleaved)")
    print(f"{'N_c':>4}{'recompute per query':>22}{'shared + gather':>18}")
    for nc in (1, 2, 4, 8):
        times = timed_interleaved(sharing_variants(mi, dr, cache, points, nc), repeats)
        print(f"{nc:>4}{1e3 * times['recompute']:>22.2f}{1e3 * times['shared']:>18.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--train-frames", type=int, default=3)
    parser.add_argument("--sharing-points", type=int, default=1 << 14,
                        help="shading points of the sharing comparison (0: skip it)")
    args = parser.parse_args()

    mi = init_backend()
    from renderers.scenes import load_scene

    scene = load_scene(args.scene, args.res)
    print(f"device: {device_info()['device_key']}  scene {args.scene} {args.res}x{args.res}, "
          f"1 spp, median of {args.repeats} interleaved repeats")
    frame_table(mi, scene, build_integrators(mi, scene, args.train_frames), args.repeats)
    if args.sharing_points:
        surface_sharing(mi, scene, args.sharing_points, args.repeats)


if __name__ == "__main__":
    main()
