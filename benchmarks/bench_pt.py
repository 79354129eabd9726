"""Benchmark: throughput of `pt` over Mitsuba's built-in `path` (goal >= 0.9).

Same process, same device, same scene, resolution, spp and max depth; the two
integrators alternate over several repeats (so drift in machine load hits both)
and the median time of each is compared. Warm-up renders (JIT compilation)
are excluded; every clock read follows ``dr.sync_thread()``.

`pt` runs twice: with its default fixed-probability roulette (survival 0.9,
the NIRC paper's setting — longer paths than `path`'s throughput rule) and with
the throughput rule, which is `path`'s estimator sample for sample.
"""

from __future__ import annotations

import argparse
import time
from statistics import median

from renderers.backend import device_info, init_backend


def _time_render(mi, scene, integrator, spp: int, seed: int) -> float:
    from renderers.timing import synchronize

    synchronize()
    start = time.perf_counter()
    image = mi.render(scene, integrator=integrator, spp=spp, seed=seed)
    synchronize(image)
    return time.perf_counter() - start


def bench_scene(mi, name: str, res: int, spp: int, repeats: int, max_depth: int) -> list[tuple]:
    from renderers.methods.pt import PTParams, path_integrator
    from renderers.scenes import load_scene

    scene = load_scene(name, res).scene
    integrators = {
        "path (Mitsuba)": mi.load_dict({"type": "path", "max_depth": max_depth}),
        "pt (rr fixed 0.9)": path_integrator(PTParams(max_depth=max_depth)),
        "pt (rr throughput)": path_integrator(PTParams(max_depth=max_depth, rr_mode="throughput")),
    }
    times: dict[str, list[float]] = {label: [] for label in integrators}
    for integrator in integrators.values():  # warm-up: compile every kernel
        _time_render(mi, scene, integrator, spp, seed=12345)
    for repeat in range(repeats):
        for label, integrator in integrators.items():
            times[label].append(_time_render(mi, scene, integrator, spp, seed=repeat))
    base = median(times["path (Mitsuba)"])
    rows = []
    for label, values in times.items():
        t = median(values)
        rows.append((name, label, t, res * res * spp / t / 1e6, base / t))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="cornell-box,cornell-glossy,door")
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--max-depth", type=int, default=8)
    args = parser.parse_args()

    mi = init_backend()
    print(f"device: {device_info()['device_key']}  res {args.res}x{args.res}  spp {args.spp}  "
          f"max_depth {args.max_depth}  median of {args.repeats}")
    print(f"{'scene':<16}{'integrator':<22}{'s/render':>10}{'Msamples/s':>12}{'vs path':>9}")
    for name in args.scenes.split(","):
        for scene, label, t, rate, ratio in bench_scene(mi, name, args.res, args.spp,
                                                        args.repeats, args.max_depth):
            print(f"{scene:<16}{label:<22}{t:>10.4f}{rate:>12.2f}{ratio:>9.3f}")
    print("goal: pt throughput >= 0.9 x path (ratio column, 'pt (rr throughput)' is the "
          "same estimator as path)")


if __name__ == "__main__":
    main()
