"""Benchmark: the direct-light methods at primary hits, interleaved: `neural-di`, `nrc-di`,
`nvc-lights`, `restir-di`, `pt-power`.

All at max_depth 2 (reference: `path` at max_depth 2, ``--ref-spp``) on
`many-lights` in its floor view (no light in the frame, so a 1-spp frame's
error is the light's, not the pixel footprint's; ``--view default`` for the
other). The caching methods pre-train ``--pretrain`` frames, then train online
every frame. Each seed runs every configuration in turn (round robin), so a
change of machine load hits all of them alike; reported per configuration,
over the seeds: the median frame time (pre-training excluded) and of its
render stage (the rest is the caches' training: records and the Adam step), MRSE and
HDR-FLIP of single frames (mean over the last 4 frames) and the MRSE of the
``--frames``-frame mean, which for the biased `neural-di` and `nrc-di` is
mostly their bias (rBias²) and for the unbiased methods falls with frames.

A last row is `neural-di` with exact visibility (the oracle
``TracedVisibility``: ``--oracle-rays`` shadow rays per light and sample,
``--oracle-spp`` samples): the bias of the product U_k · V̄_k itself
(penumbrae), which no training removes.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from benchmarks.bench_restir import load
from renderers.backend import device_info, init_backend

#: (method, params, spp) of each row; the caching methods get ``pretrain_frames``.
CONFIGS: tuple[tuple[str, dict[str, Any], int], ...] = (
    ("neural-di", {}, 1),
    ("nrc-di", {}, 1),
    ("nvc-lights", {"max_depth": 2}, 1),
    ("restir-di", {}, 1),
    ("pt-power", {"max_depth": 2}, 1),
    ("pt-power", {"max_depth": 2}, 16),
)


def run(scene: Any, reference: np.ndarray, name: str, params: dict[str, Any], spp: int,
        frames: int, seed: int) -> tuple[float, float, float, float, float]:
    """(median frame seconds, median render-stage seconds, MRSE and HDR-FLIP of single
    frames, MRSE of the mean)."""
    from metrics.errors import mrse
    from metrics.flip import flip_hdr, hdr_exposures
    from renderers.methods import METHODS, parse_params
    from renderers.methods.base import FrameHooks

    images: list[np.ndarray] = []
    output = METHODS[name].render(
        scene, parse_params(name, params), seed_parts=("bench-di", name, seed), spp=spp,
        frames=frames, hooks=FrameHooks(on_frame=lambda _i, rgb, _acc: images.append(rgb)))
    last = images[-4:]
    exposures = hdr_exposures(reference)
    return (output.timings["frame_median_s"], output.timings["stages"]["render"]["median_s"],
            float(np.mean([mrse(image, reference) for image in last])),
            float(np.mean([flip_hdr(reference, image, exposures)[0] for image in last])),
            mrse(output.accumulated, reference))


def oracle_error(mi: Any, scene: Any, reference: np.ndarray, rays: int, spp: int) -> float:
    """MRSE of `neural-di` with traced (exact, area-averaged) visibility."""
    from metrics.errors import mrse
    from renderers.integrators import neural_di, register_plugins

    register_plugins()
    integrator = mi.load_dict({"type": neural_di.PLUGIN_NAME})
    integrator.with_visibility(neural_di.TracedVisibility(rays))
    image = np.asarray(mi.render(scene.scene, integrator=integrator, spp=spp, seed=5))
    return mrse(image[..., :3], reference)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--view", choices=("default", "floor"), default="floor")
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--pretrain", type=int, default=32)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--ref-spp", type=int, default=4096)
    parser.add_argument("--oracle-rays", type=int, default=4)
    parser.add_argument("--oracle-spp", type=int, default=64)
    args = parser.parse_args()

    from renderers.methods import METHODS

    mi = init_backend()
    scene = load(mi, args.view, args.res)
    reference = np.asarray(mi.render(scene.scene, spp=args.ref_spp, seed=99,
                                     integrator=mi.load_dict({"type": "path", "max_depth": 2})))
    reference = reference[..., :3]
    configs = [(name, {**params, **({"pretrain_frames": args.pretrain}
                                    if "pretrain_frames" in METHODS[name].params.model_fields
                                    else {})}, spp) for name, params, spp in CONFIGS]
    rows: dict[int, list[tuple[float, ...]]] = {i: [] for i in range(len(configs))}
    for seed in range(args.seeds):
        for index, (name, params, spp) in enumerate(configs):
            rows[index].append(run(scene, reference, name, params, spp, args.frames, seed))

    print(f"device: {device_info()['device_key']}  many-lights ({args.view} view) "
          f"{args.res}x{args.res}  {args.frames} frames after {args.pretrain} pre-training "
          f"(caches)  {args.seeds} seeds, interleaved")
    print(f"{'method':<12}{'spp':>4}{'ms/frame':>10}{'render ms':>11}{'MRSE':>9}{'FLIP':>8}"
          f"{'MRSE(mean)':>12}")
    for index, (name, _params, spp) in enumerate(configs):
        values = np.asarray(rows[index])
        seconds, render_s = np.median(values[:, :2], axis=0)
        error, flip, mean_error = values[:, 2:].mean(axis=0)
        print(f"{name:<12}{spp:>4}{seconds * 1e3:>10.1f}{render_s * 1e3:>11.1f}{error:>9.4f}"
              f"{flip:>8.4f}{mean_error:>12.5f}", flush=True)
    oracle = oracle_error(mi, scene, reference, args.oracle_rays, args.oracle_spp)
    print(f"neural-di with exact visibility (oracle, {args.oracle_rays} rays x "
          f"{args.oracle_spp} spp): MRSE {oracle:.5f}")


if __name__ == "__main__":
    main()
