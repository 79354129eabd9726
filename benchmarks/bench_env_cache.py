"""Benchmark: the environment's visibility cache against NIRC predicting the same direct
light (the NIRC paper's Fig. 11), on `sky`.

Both are `nvc-env`'s unbiased two-level estimator of the environment's direct
light (N_c 7 env-map directions + one shadow-ray residual, max_depth 2) and
differ only in what the cache predicts: ``target='visibility'`` V(x, w) (the
NVC: position hash grid + SH direction, 2 x 32 MLP, sigmoid, L2, Adam 0.05 ->
0.001) or ``target='radiance'`` L_env(w) V(x, w), RGB (NIRC's inputs, loss
and optimizer, its MLP cut to 2 hidden layers of 64 as the paper cuts both).
All train online, one step per frame on the same records (8192 shadow rays:
4096 camera first hits + 4096 vertices one bounce further, one p_env
direction each), from an untrained cache; the radiance cache once with
NIRC's own optimizer and once with the NVC's (``VARIANTS``).

Reports:

(a) reconstruction: after frames 1, 2, 4, ... of training, the relative
    squared error of the predicted radiance on a fixed held-out set of
    records, sum (n - L_env V)^2 / sum (L_env V)^2 over luminance, the exact
    V from the record's shadow ray (the visibility cache predicts L_env V_c);
    and its worst rise, the largest factor by which a frame's error exceeds
    the best of the frames before it (training stability; 1: never rose);
(b) the estimator: MRSE of 1-spp frames (per-pixel variance, the estimator
    being unbiased) against a 4096-spp `path` reference, after training, next
    to `pt` at 1 spp (Mitsuba's ``path``, max_depth 2);
(c) time: render (loop + deferred cache queries) of a 1-spp frame and one
    training frame (records + step), medians of interleaved runs, as ratios.

The CPU is shared: read the ratios, not the milliseconds.
"""

from __future__ import annotations

import argparse
import statistics
from typing import Any

import numpy as np

from benchmarks.bench_cache import timed_interleaved
from renderers.backend import device_info, init_backend

#: The caches compared: the NVC; NIRC's network with its own optimizer (Adam lr 1e-2,
#: weight EMA 0.99); and with the NVC's (lr 0.05 -> 0.001 over 200 steps, no EMA),
#: which learns faster from one step per frame (a check that the radiance cache's
#: result is not its optimizer's).
VARIANTS: dict[str, dict[str, Any]] = {
    "visibility": {"target": "visibility"},
    "radiance": {"target": "radiance"},
    "radiance/nvc-opt": {"target": "radiance",
                         "cache": {"ema_decay": None,
                                   "optimizer": {"lr": 0.05, "lr_end": 1e-3,
                                                 "lr_decay_steps": 200}}},
}
HELD_OUT_SEED = 1_000_003


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def held_out(scene: Any, points: int) -> tuple[Any, np.ndarray, np.ndarray]:
    """Radiance records (NIRC's inputs) of a fixed seed, their exact L_env V and L_env
    (luminance; invalid records 0)."""
    import drjit as dr
    import mitsuba as mi

    from renderers.integrators.nvc_env import visibility_records

    records = visibility_records(scene.scene, points, HELD_OUT_SEED, "radiance")
    valid = records.valid.numpy()
    truth = luminance(np.stack([t.numpy() for t in records.target], axis=1))
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(records.direction))
    si.wi = -records.direction
    env = scene.scene.environment().eval(si)
    env = luminance(np.stack([env[i].numpy() for i in range(3)], axis=1))
    return records, np.where(valid, truth, 0.0), np.where(valid, env, 0.0)


def predicted_radiance(cache: Any, target: str, records: Any, env: np.ndarray) -> np.ndarray:
    """The cache's L_env V on the held-out records (luminance): L_env V_c for the
    visibility cache, the (clamped) prediction of the radiance cache."""
    if target == "visibility":
        values = cache.query(cache.surface_features(records.position), records.direction)
        return env * values[0].numpy()
    inputs = {name: getattr(records, name) for name in ("position", "normal", "roughness",
                                                        "albedo")}
    values = cache.query(cache.surface_features(**inputs), records.direction)
    return luminance(np.stack([v.numpy() for v in values], axis=1))   # clamped >= 0


def worst_rise(errors: list[float]) -> float:
    """Training stability: the largest factor by which a frame's error exceeds the best
    error of the frames before it (1: the error never rose)."""
    best, worst = errors[0], 1.0
    for error in errors[1:]:
        worst, best = max(worst, error / best), min(best, error)
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--frames", type=int, default=256, help="training frames")
    parser.add_argument("--render-frames", type=int, default=16,
                        help="1-spp frames for the MRSE")
    parser.add_argument("--ref-spp", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()

    mi = init_backend()
    from metrics.errors import mrse
    from renderers.methods.nvc_env import NVCEnvParams, build, train_frame
    from renderers.scenes import load_scene
    from renderers.timing import StageTimer

    scene = load_scene("sky", args.res)
    records, truth, env = held_out(scene, 4096)
    truth_energy = float(np.sum(truth ** 2))

    params = {t: NVCEnvParams(max_depth=2, nc=7, **v) for t, v in VARIANTS.items()}
    built = {t: build(scene, params[t], seed=0) for t in VARIANTS}
    curve: dict[str, list[float]] = {t: [] for t in VARIANTS}
    for frame in range(args.frames):
        for t in VARIANTS:
            cache = built[t][1]
            train_frame(scene, cache, params[t], frame, StageTimer())
            error = predicted_radiance(cache, params[t].target, records, env) - truth
            curve[t].append(float(np.sum(error ** 2)) / truth_energy)

    reference = np.asarray(mi.render(scene.scene, integrator=mi.load_dict(
        {"type": "path", "max_depth": 2}), spp=args.ref_spp, seed=77))
    path = mi.load_dict({"type": "path", "max_depth": 2})

    def frame_mrse(integrator: Any) -> float:
        return statistics.mean(
            mrse(np.asarray(mi.render(scene.scene, integrator=integrator, spp=1, seed=s))[..., :3],
                 reference) for s in range(args.render_frames))

    errors = {t: frame_mrse(built[t][0]) for t in VARIANTS}
    errors["pt"] = frame_mrse(path)

    def render(integrator: Any):
        return lambda: mi.render(scene.scene, integrator=integrator, spp=1, seed=3)

    def training(t: str):
        return lambda: (train_frame(scene, built[t][1], params[t], 5, StageTimer()),
                        built[t][1].inference_parameters())[1]

    seconds = timed_interleaved({
        "pt": render(path),
        **{t: render(built[t][0]) for t in VARIANTS},
        **{f"train {t}": training(t) for t in VARIANTS},
    }, args.repeats)

    print(f"device: {device_info()['device_key']}  sky {args.res}x{args.res}, max_depth 2, "
          f"N_c 7, unbiased; median of {args.repeats} interleaved runs")
    print("(a) relative squared error of the predicted L_env V on 8192 held-out records")
    marks = [f for f in (1, 2, 4, 8, 16, 32, 64, 128, 256) if f <= args.frames]
    print(f"{'frames':<18}" + "".join(f"{f:>8}" for f in marks) + f"{'worst rise':>12}")
    for t in VARIANTS:
        print(f"{t:<18}" + "".join(f"{curve[t][f - 1]:>8.3f}" for f in marks)
              + f"{worst_rise(curve[t]):>11.2f}x")
    print(f"(b) MRSE of a 1-spp frame (mean of {args.render_frames}; 4096-spp reference): "
          + ", ".join(f"{name} {value:.4f}" for name, value in errors.items()))
    print(f"(c) 1-spp frame: pt {seconds['pt'] * 1e3:.1f} ms; "
          + ", ".join(f"{t} {seconds[t] * 1e3:.1f} ms = {seconds[t] / seconds['pt']:.2f}x pt"
                      for t in VARIANTS)
          + "; training frame: " + ", ".join(
              f"{t} {seconds['train ' + t] * 1e3:.1f} ms" for t in VARIANTS))
    ratio = {t: errors[t] * seconds[t] for t in VARIANTS}
    print("    MRSE x frame time, visibility / each radiance cache (< 1: the NVC is more "
          "efficient): " + ", ".join(f"{t} {ratio['visibility'] / ratio[t]:.2f}"
                                     for t in VARIANTS if t != "visibility"))


if __name__ == "__main__":
    main()
