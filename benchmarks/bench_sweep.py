"""Benchmark: the overhead of the adaptive equal-bias sweep over its unavoidable renders.

Runs a 20-value eps sweep (``--eps 0.05:1.0``) on a fresh data folder and
compares its wall time with the sum of the renders it cannot avoid, each
measured inside the same run (device synchronised before every clock read):
the reference, the caches' training frames + converged cache-at-v1 images,
and the 20 x K x F timed 1-spp frames. Everything else — JIT compilation,
warm-up frames, metrics (FLIP), artifacts, database writes, plots — is
overhead. Goal: ratio <= 1.2. A first, smaller sweep in another
folder warms the on-disk kernel cache, so compilation that a user pays once
per machine is not counted; the cold ratio is printed too.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from jobs.protocol.ranges import parse_range


def _sweep(data_dir: Path, **spec_values):
    from jobs.protocol.spec import ReferenceSpec, SweepSpec
    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.sweeps.sweep import run_sweep

    settings = Settings(data_dir=data_dir)
    store = open_store(settings)
    spec = SweepSpec(reference=ReferenceSpec(spp=spec_values.pop("ref_spp")), **spec_values)
    start = time.perf_counter()
    result = run_sweep(spec, store, settings)
    return result, time.perf_counter() - start, store


def _unavoidable(result, store) -> dict[str, float]:
    """Seconds of the renders the sweep cannot avoid, from what it stored."""
    run_ids = {row["run_id"] for row in result.rows}
    points = 0.0
    reference_id = None
    for run_id in run_ids:
        run = store.get_run(run_id)
        reference_id = run.reference_id
        for seed in run.seed_results:
            points += sum(sum(frame.values()) for frame in seed.timings["per_frame"])
    with store.session() as session:
        from jobs.record.models import CacheSnapshot, Reference

        reference_s = session.get(Reference, reference_id).render_seconds
        snapshots = session.query(CacheSnapshot).all()
        training = sum(s.stats["train_frames_s"] for s in snapshots)
        v1 = sum(s.stats["v1_render_s"] for s in snapshots)
    return {"reference": reference_s, "cache training frames": training,
            "cache-at-v1 images": v1, "1-spp sweep frames": points}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--train-frames", type=int, default=20)
    parser.add_argument("--v1-spp", type=int, default=64)
    parser.add_argument("--ref-spp", type=int, default=1024)
    args = parser.parse_args()

    from renderers.backend import device_info, init_backend

    init_backend()
    common = dict(scene=args.scene, resolution=args.res, seeds=args.seeds,
                  v1_spp=args.v1_spp, ref_spp=args.ref_spp, equal_time=False)
    with tempfile.TemporaryDirectory() as folder:
        _, cold_s, _ = _sweep(Path(folder) / "warm", eps=[0.5, 1.0], train_frames=2, **common)
        result, wall, store = _sweep(Path(folder) / "measured", eps=parse_range("0.05:1.0"),
                                     train_frames=args.train_frames, **common)
        parts = _unavoidable(result, store)
        store.close()
    total = sum(parts.values())
    print(f"device: {device_info()['device_key']}  scene {args.scene} {args.res}x{args.res}, "
          f"20 eps x K={args.seeds} x 2 methods, {args.train_frames} training frames per cache")
    for name, seconds in parts.items():
        print(f"  {name:<24}{seconds:8.2f} s")
    print(f"  {'sum (unavoidable)':<24}{total:8.2f} s")
    print(f"  {'sweep wall time':<24}{wall:8.2f} s")
    print(f"overhead ratio (warm kernel cache): {wall / total:.3f}  (goal <= 1.2)")
    print(f"warm-up sweep (2 eps, 2 training frames, compiles kernels): {cold_s:.1f} s")


if __name__ == "__main__":
    main()
