"""Benchmark: `restir-di` against `nvc-lights` and `pt-power`, direct light at primary hits.

All three at max_depth 2 (the emission the camera sees plus direct light at the
first hit: what `restir-di` computes) on `many-lights`, in its default view or
the floor view (``renderers.scenes.many_lights.floor_view``: no light in the
frame). Each configuration runs ``--frames`` frames through the method's own
frame loop (warm-up excluded) for ``--seeds`` seeds; reported: the median frame
time, and MRSE and HDR-FLIP of single frames (the mean over the last 4 frames:
the steady state of reuse and of the cache's online training) against `path`
at ``--ref-spp``. Equal time is read off the table: `pt-power` at several spp.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from renderers.backend import device_info, init_backend

#: (method, params, spp) of each row.
CONFIGS: tuple[tuple[str, dict[str, Any], int], ...] = (
    ("restir-di", {}, 1),
    ("restir-di", {"spatial": False}, 1),
    ("restir-di", {"temporal": False, "spatial": False}, 1),
    ("nvc-lights", {"max_depth": 2}, 1),
    ("pt-power", {"max_depth": 2}, 4),
    ("pt-power", {"max_depth": 2}, 16),
    ("pt-power", {"max_depth": 2}, 32),
)


def load(mi: Any, view: str, res: int) -> Any:
    from renderers.scenes import load_scene
    from renderers.scenes.many_lights import floor_view
    from renderers.scenes.parts import set_film_resolution

    scene = load_scene("many-lights", res)
    if view == "floor":
        scene.scene = mi.load_dict(set_film_resolution(floor_view(), res, res), optimize=False)
    return scene


def run(scene: Any, reference: np.ndarray, name: str, params: dict[str, Any], spp: int,
        frames: int, seed: int) -> tuple[float, float, float]:
    """(median frame seconds, MRSE, HDR-FLIP) of one seed; errors of single frames."""
    from metrics.errors import mrse
    from metrics.flip import flip_hdr, hdr_exposures
    from renderers.methods import METHODS, parse_params
    from renderers.methods.base import FrameHooks

    images: list[np.ndarray] = []
    output = METHODS[name].render(
        scene, parse_params(name, params), seed_parts=("bench-restir", name, seed), spp=spp,
        frames=frames, hooks=FrameHooks(on_frame=lambda _i, rgb, _acc: images.append(rgb)))
    last = images[-4:]
    exposures = hdr_exposures(reference)
    return (output.timings["frame_median_s"],
            float(np.mean([mrse(image, reference) for image in last])),
            float(np.mean([flip_hdr(reference, image, exposures)[0] for image in last])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--view", choices=("default", "floor"), default="floor")
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--ref-spp", type=int, default=8192)
    args = parser.parse_args()

    mi = init_backend()
    scene = load(mi, args.view, args.res)
    reference = np.asarray(mi.render(scene.scene, spp=args.ref_spp, seed=99,
                                     integrator=mi.load_dict({"type": "path", "max_depth": 2})))
    print(f"device: {device_info()['device_key']}  many-lights ({args.view} view) "
          f"{args.res}x{args.res}  {args.frames} frames  {args.seeds} seeds")
    print(f"{'method':<12}{'params':<42}{'spp':>4}{'ms/frame':>10}{'MRSE':>9}{'FLIP':>8}")
    for name, params, spp in CONFIGS:
        rows = [run(scene, reference[..., :3], name, params, spp, args.frames, seed)
                for seed in range(args.seeds)]
        seconds, error, flip = np.mean(rows, axis=0)
        print(f"{name:<12}{str(params):<42}{spp:>4}{seconds * 1e3:>10.1f}{error:>9.4f}"
              f"{flip:>8.4f}", flush=True)


if __name__ == "__main__":
    main()
