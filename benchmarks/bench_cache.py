"""Benchmark: cost of the neural cache on this device (nirc preset by default).

Reports, measured in one run (docs/design.md, "Performance goals"):

- one neural query (hash grid + SH + MLP, CoopVec) per point, and its parts:
  the hash-grid encoding alone and the MLP alone;
- N_c = 1..32 directions per shading point with the per-surface features
  recomputed per direction (``query_unshared``), shared (NIRC paper
  Sec. 4.5, encodings only: ``split_first_layer=False``), and shared together
  with the surface part of the first layer (the default), each as a symbolic
  loop over the N_c directions like an integrator would run it;
- CoopVec vs tensor-mode inference;
- one path-traced sample of the Cornell box (Mitsuba ``path``), timed
  interleaved with the queries, and one query (default and the ``small``
  preset's 2x32 MLP) as a multiple of it (goal: <= 0.5); the same query and
  PT sample on 1 thread; the LLVM vector width of the query kernels;
- one training step (tensor mode) at batch 16384 and at the training
  budget's small-frame batch 1024, with the reproducible fixed-point
  hash-grid gradient, with Dr.Jit's float atomics and with the small preset,
  interleaved per batch size (docs/training.md, "Speed of the neural work").
  ``--skip-nc`` leaves out the N_c table.

Protocol: every measurement is preceded by a warm-up call (JIT compilation
excluded); inputs are evaluated before the clock starts; outputs are
evaluated and ``dr.sync_thread()`` called before it stops; the median of
``--repeats`` runs is reported.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from statistics import median
from typing import Any

from renderers.backend import device_info, init_backend


def timed_interleaved(fns: dict[str, Callable[[], Any]], repeats: int) -> dict[str, float]:
    """Median seconds of each function (outputs evaluated, device synchronised).

    Every function is warmed up first (JIT compilation excluded); the timed
    runs then alternate between the functions, so that a change in machine
    load (the CPU is shared) affects all of them alike.
    """
    import drjit as dr

    for fn in fns.values():
        dr.eval(fn())
        dr.sync_thread()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            dr.sync_thread()
            start = time.perf_counter()
            out = fn()
            dr.eval(out)
            dr.sync_thread()
            times[name].append(time.perf_counter() - start)
    return {name: median(values) for name, values in times.items()}


def timed(fn: Callable[[], Any], repeats: int) -> float:
    """Median seconds of ``fn`` after a warm-up (see :func:`timed_interleaved`)."""
    return timed_interleaved({"fn": fn}, repeats)["fn"]


def _inputs(mi, dr, n: int, seed: int = 0) -> dict[str, Any]:
    """Random evaluated shading inputs in the unit box."""
    rng = dr.rng(seed)

    def unit_vectors() -> Any:
        return dr.normalize(mi.Vector3f(rng.normal(mi.Float, n), rng.normal(mi.Float, n),
                                        rng.normal(mi.Float, n)))

    values = {
        "position": mi.Point3f(rng.random(mi.Float, n), rng.random(mi.Float, n),
                               rng.random(mi.Float, n)),
        "normal": unit_vectors(),
        "roughness": rng.random(mi.Float, n),
        "albedo": mi.Color3f(rng.random(mi.Float, n), rng.random(mi.Float, n),
                             rng.random(mi.Float, n)),
        "direction": unit_vectors(),
    }
    dr.eval(values)
    return values


def _direction(mi, dr, j: Any, n: Any) -> Any:
    """A cheap direction that depends on the loop counter (stands in for a BSDF sample)."""
    t = mi.Float(j) * 0.7
    return dr.normalize(n + mi.Vector3f(dr.sin(t), dr.cos(t), 0.3))


def nc_samples(mi, dr, cache, inputs: dict[str, Any], nc: int,
               shared: bool) -> Callable[[], Any]:
    """A function summing ``nc`` cache samples per shading point (like Eq. 12)."""
    pos, nrm, rough, alb = (inputs[k] for k in ("position", "normal", "roughness", "albedo"))
    # A zero the compiler cannot see: "recomputed" inputs depend on the loop
    # counter through it, so LLVM cannot hoist the loop-invariant encoding out
    # of the loop (which would silently turn the unshared variant into the
    # shared one).
    zero = dr.opaque(mi.Float, 0.0)

    def run() -> Any:
        # Shared: encoded once, before the loop (loop-invariant in the kernel).
        surface = cache.surface_features(pos, nrm, rough, alb) if shared else None

        def body(L: Any, j: Any) -> tuple[Any, Any]:
            d = _direction(mi, dr, j, nrm)
            if shared:
                q = cache.query(surface, d)
            else:
                jz = mi.Float(j) * zero
                q = cache.query_unshared(pos + jz, nrm + jz, rough + jz, alb + jz, d)
            return L + q, j + 1

        # A symbolic loop like an integrator's N_c loop (the functional form of
        # `while j < nc` under @dr.syntax, which cannot see closure variables).
        L, _ = dr.while_loop((mi.Color3f(0), mi.UInt32(0)), lambda L, j: j < nc, body,
                             label="N_c cache samples")
        return L

    return run


def bench_training(mi, dr, caches, config, batch: int, steps: int,
                   repeats: int, small_config: Any = None) -> dict[str, float]:
    """Median seconds per training step (tensor mode) at ``batch``, with the
    reproducible grid gradient and with Dr.Jit's float atomics (and, given
    ``small_config``, with that network), interleaved in one run."""
    x = _inputs(mi, dr, batch * 4, seed=1)
    p, d = x["position"], x["direction"]
    target = mi.Color3f(1 + 0.5 * dr.sin(3 * p.x) + 0.3 * d.z, 1 + p.y * d.x, 0.5 + p.z)
    records = caches.TrainingRecords(position=p, target=target, normal=x["normal"],
                                     roughness=x["roughness"], albedo=x["albedo"],
                                     direction=d)
    variants = {}
    for name, deterministic in (("fixed-point", True), ("atomics", False)):
        variants[name] = caches.NeuralCache(config, [0, 0, 0], [1, 1, 1], seed=0,
                                            deterministic=deterministic)
    if small_config is not None:
        variants["small"] = caches.NeuralCache(small_config, [0, 0, 0], [1, 1, 1], seed=0)

    def train(cache: Any) -> Callable[[], None]:
        def run() -> None:
            cache.train(records, steps=steps, batch_size=batch)  # synchronises itself
        return run

    times = timed_interleaved({k: train(c) for k, c in variants.items()}, repeats)
    return {k: t / steps for k, t in times.items()}


def path_sample_fn(mi, spp: int = 4) -> tuple[Callable[[], Any], int]:
    """A render of the Cornell box (Mitsuba path, max_depth 8) and its sample count."""
    scene = mi.load_dict(mi.cornell_box())
    integrator = mi.load_dict({"type": "path", "max_depth": 8})
    width, height = scene.sensors()[0].film().size()
    return (lambda: mi.render(scene, integrator=integrator, spp=spp, seed=1),
            width * height * spp)


def bench_path_sample(mi, repeats: int, spp: int = 4) -> float:
    """Seconds per path-traced sample of the Cornell box (Mitsuba path, max_depth 8)."""
    fn, samples = path_sample_fn(mi, spp)
    return timed(fn, repeats) / samples


def with_threads(dr, count: int, fn: Callable[[], Any]) -> Callable[[], Any]:
    """``fn`` run on ``count`` worker threads (evaluated inside; the pool restored)."""
    def run() -> Any:
        previous = dr.thread_count()
        dr.set_thread_count(count)
        try:
            out = fn()
            dr.eval(out)
            dr.sync_thread()
        finally:
            dr.set_thread_count(previous)
        return out
    return run


def vector_width(dr, fn: Callable[[], Any]) -> str:
    """The float vector widths in the LLVM IR of the kernels ``fn`` launches."""
    import re

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        dr.eval(fn())
        dr.sync_thread()
        widths: set[int] = set()
        for k in dr.kernel_history():
            if k["type"] == dr.KernelType.JIT and "ir" in k:
                ir = k["ir"].getvalue() if hasattr(k["ir"], "getvalue") else str(k["ir"])
                widths |= {int(w) for w in re.findall(r"<(\d+) x float>", ir)}
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return f"max <{max(widths)} x float>" if widths else "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log2-points", type=int, default=18,
                        help="queries per measurement = 2^this (default 18)")
    parser.add_argument("--log2-shading-points", type=int, default=14,
                        help="shading points in the N_c table (default 2^14)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--train-batch", type=int, default=16384)
    parser.add_argument("--small-train-batch", type=int, default=1024,
                        help="second batch size, the training budget's at small frames")
    parser.add_argument("--train-steps", type=int, default=8)
    parser.add_argument("--skip-nc", action="store_true", help="skip the N_c table")
    args = parser.parse_args()

    mi = init_backend()
    import drjit as dr

    import renderers.caches as caches
    from renderers.caches.encodings import to_tensor
    from renderers.caches.inference import PackedMLP

    config = caches.nirc_config()
    small = caches.nirc_config(preset="small")
    cache = caches.NeuralCache(config, [0, 0, 0], [1, 1, 1], seed=0)
    cache_small = caches.NeuralCache(small, [0, 0, 0], [1, 1, 1], seed=0)
    # Same weights (same seed), first layer not split: encodings-only sharing.
    cache_concat = caches.NeuralCache(config, [0, 0, 0], [1, 1, 1], seed=0,
                                      split_first_layer=False)
    info = cache.describe()
    n = 1 << args.log2_points
    x = _inputs(mi, dr, n)
    us = 1e6 / n
    print(f"device: {device_info()['device_key']}  variant {mi.variant()}  "
          f"median of {args.repeats} (warm-up excluded)")
    print(f"cache: nirc preset, {info['n_inputs']} inputs -> MLP {config.mlp.width}x"
          f"{config.mlp.hidden_layers} -> {info['n_outputs']}; hash grid "
          f"{config.position.n_levels}x{config.position.n_features_per_level}, table "
          f"2^{config.position.log2_hashmap_size}, {info['hashgrid_params']:,} params; "
          f"SH {config.direction.sh_bands} bands")

    # ---- One neural query and its parts ----
    encoded = cache.encoder.surface(x["position"], x["normal"], x["roughness"], x["albedo"])
    rows = [*encoded, *cache.encoder.direction(x["direction"])]
    rows = [r + dr.zeros(mi.Float, n) if dr.width(r) == 1 else r for r in rows]
    dr.eval(rows)
    full_net = PackedMLP(cache.tensor_network, len(rows), split_first_layer=False)
    tensor_in = to_tensor(rows)
    dr.eval(tensor_in)
    records = caches.TrainingRecords(position=x["position"], target=x["albedo"],
                                     normal=x["normal"], roughness=x["roughness"],
                                     albedo=x["albedo"], direction=x["direction"])
    args5 = (x["position"], x["normal"], x["roughness"], x["albedo"], x["direction"])
    path_fn, path_samples = path_sample_fn(mi)
    t = timed_interleaved({
        "path": path_fn,
        "small_split": lambda: cache_small.query_unshared(*args5),
        "full_split_1thread": with_threads(dr, 1, lambda: cache.query_unshared(*args5)),
        "path_1thread": with_threads(dr, 1, path_fn),
        "full": lambda: cache_concat.query_unshared(*args5),
        "full_split": lambda: cache.query_unshared(*args5),
        "grid": lambda: cache.encoder.position.encode(x["position"]),
        "mlp": lambda: full_net.finish(rows, []),
        "mlp_tensor": lambda: cache.tensor_network(tensor_in),
        "full_tensor": lambda: cache.predict_tensor(records),
    }, args.repeats)
    full, grid_only, mlp_only = t["full"], t["grid"], t["mlp"]
    mlp_tensor, full_tensor = t["mlp_tensor"], t["full_tensor"]
    header = f"per point (2^{args.log2_points} points)"
    print(f"\n{header:<50}{'us/point':>10}")
    for label, seconds in [
        ("neural query: hash grid + SH + MLP (CoopVec)", full),
        ("  same, first layer split (default cache)", t["full_split"]),
        ("hash-grid encoding only", grid_only),
        ("MLP only (CoopVec, inputs precomputed)", mlp_only),
        ("MLP only (tensor mode, inputs precomputed)", mlp_tensor),
        ("neural query, tensor mode (predict_tensor)", full_tensor),
    ]:
        print(f"{label:<50}{seconds * us:>10.3f}")
    print(f"CoopVec vs tensor-mode inference: full query {full_tensor / full:.2f}x faster, "
          f"MLP alone {mlp_tensor / mlp_only:.2f}x faster")
    t_path = t["path"] / path_samples
    q_default, q_small = t["full_split"] / n, t["small_split"] / n
    print(f"\nagainst one path-traced sample of mi.cornell_box() (Mitsuba path, max_depth 8; "
          f"same run): {t_path * 1e6:.3f} us/sample (goal: a query <= 0.5 sample)")
    print(f"  default query (64x4, split)  {q_default * 1e6:7.3f} us = "
          f"{q_default / t_path:.2f} PT samples")
    print(f"  small preset (32x2, split)   {q_small * 1e6:7.3f} us = "
          f"{q_small / t_path:.2f} PT samples")
    print(f"  1 thread instead of {dr.thread_count()}: query {t['full_split_1thread'] / n * 1e6:.3f}"
          f" us ({t['full_split_1thread'] / t['full_split']:.2f}x), PT sample "
          f"{t['path_1thread'] / path_samples * 1e6:.3f} us "
          f"({t['path_1thread'] / t['path']:.2f}x)")
    print(f"  LLVM vector width of the query kernels: "
          f"{vector_width(dr, lambda: cache.query_unshared(*args5))}")

    # ---- N_c directions per shading point: shared vs recomputed surface features ----
    m = 1 << args.log2_shading_points
    xs = _inputs(mi, dr, m, seed=2)
    if not args.skip_nc:
        print(f"\nN_c directions per shading point ({m} shading points, symbolic loop over N_c;"
              " us per shading point)")
        print("  recomputed: query_unshared per direction; shared enc: encodings once per point;"
              "\n  shared enc+L1: encodings and first-layer surface part once per point (default)")
        print(f"{'N_c':>4}{'recomputed':>12}{'shared enc':>12}{'shared enc+L1':>15}"
              f"{'recomp/default':>16}{'default us/query':>18}{'vs N_c x unshared N_c=1':>25}")
        base = None
        for nc in (1, 2, 4, 8, 16, 32):
            tn = timed_interleaved({
                "recomputed": nc_samples(mi, dr, cache_concat, xs, nc, shared=False),
                "shared_enc": nc_samples(mi, dr, cache_concat, xs, nc, shared=True),
                "shared_l1": nc_samples(mi, dr, cache, xs, nc, shared=True),
            }, args.repeats)
            t_un, t_enc, t_l1 = tn["recomputed"], tn["shared_enc"], tn["shared_l1"]
            base = base or t_un
            print(f"{nc:>4}{t_un / m * 1e6:>12.3f}{t_enc / m * 1e6:>12.3f}{t_l1 / m * 1e6:>15.3f}"
                  f"{t_un / t_l1:>16.2f}{t_l1 / m / nc * 1e6:>18.3f}{t_l1 / (nc * base):>25.2f}")

    # ---- Training ----
    for b in (args.train_batch, args.small_train_batch):
        tt = bench_training(mi, dr, caches, config, b, args.train_steps, repeats=3,
                            small_config=small)
        t_det, t_atomic, t_small = tt["fixed-point"], tt["atomics"], tt["small"]
        print(f"\ntraining step, batch {b} (tensor mode, Adam over MLP + hash grid, EMA; "
              f"one interleaved run):")
        print(f"  reproducible fixed-point grid gradient (default): {t_det * 1e3:8.1f} ms/step")
        print(f"  Dr.Jit float-atomic grid gradient:               {t_atomic * 1e3:8.1f} ms/step")
        print(f"  small preset (32x2 MLP), fixed-point:            {t_small * 1e3:8.1f} ms/step"
              f"  ({t_det / t_small:.2f}x faster than default)")


if __name__ == "__main__":
    main()
