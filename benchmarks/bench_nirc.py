"""Benchmark: NIRC frame time against N_c, next to PT, on one scene and device.

Prints the render-stage time of one 1-spp frame of biased NIRC (BTH) for
N_c = 1, 2, 4, 8, 16, 32 and of unbiased NIRC (3,1,1), the training-stage
times (training paths, the Adam steps of the frame's training budget), and PT 1 spp — all measured in this run,
medians over repeats, warm-up excluded, device synchronised before each clock
read. The per-shading-point cost of sharing the surface encoding across N_c
directions is in ``benchmarks.bench_cache``.
"""

from __future__ import annotations

import argparse
import math
from statistics import median

from renderers.backend import device_info, init_backend


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    mi = init_backend()
    from renderers.methods import nirc as nirc_method
    from renderers.methods import parse_params
    from renderers.methods.budget import frame_training_budget
    from renderers.methods.cached import train_once
    from renderers.methods.pt import path_integrator
    from renderers.scenes import load_scene
    from renderers.timing import StageTimer, synchronize

    scene = load_scene(args.scene, args.res)

    def frame_seconds(integrator) -> float:
        times = []
        for repeat in range(args.repeats + 1):
            timer = StageTimer()
            with timer.stage("render"):
                image = mi.render(scene.scene, integrator=integrator, spp=1, seed=repeat)
                synchronize(image)
            if repeat:  # the first render compiles
                times.append(timer.seconds["render"])
        return median(times)

    pt_s = frame_seconds(path_integrator(parse_params("pt", {})))
    print(f"device: {device_info()['device_key']}  scene {args.scene} {args.res}x{args.res}, "
          f"1 spp, median of {args.repeats}")
    print(f"{'method':<28}{'ms/frame (render)':>18}{'vs PT':>8}")
    print(f"{'PT 1 spp':<28}{1e3 * pt_s:>18.2f}{1.0:>8.2f}")
    configs = [("biased", [nc]) for nc in (1, 2, 4, 8, 16, 32)] + [("unbiased", [3, 1, 1])]
    training: dict[str, list[float]] = {}
    for estimator, nc in configs:
        params = parse_params("nirc", {"estimator": estimator, "nc": nc})
        integrator, trainer, cache = nirc_method.build(scene, params, seed=1)
        budget = frame_training_budget(math.prod(scene.resolution), params, cache.config)
        for frame in range(3):  # a little training so the cache is not all zeros
            timer = StageTimer()
            train_once(cache, trainer, scene, budget, seed=frame, timer=timer)
            if frame:
                for stage, seconds in timer.seconds.items():
                    training.setdefault(stage, []).append(seconds)
        integrator.cache = cache
        seconds = frame_seconds(integrator)
        label = f"NIRC {estimator} N_c={','.join(map(str, nc))}"
        print(f"{label:<28}{1e3 * seconds:>18.2f}{seconds / pt_s:>8.2f}")
    for stage, values in training.items():
        print(f"training stage {stage:<16}{1e3 * median(values):>12.2f} ms per frame "
              f"({budget.paths} paths, {budget.steps} x {budget.batch_size} records)")


if __name__ == "__main__":
    main()
