"""Benchmark: error against time per frame, with each method's speed-up at equal error over the
strongest PT (docs/pareto.md).

Runs a small ``nirc-bench pareto`` (jobs/pareto/pareto.py) on a fresh data
folder: the paper's PT and the strongest PT's candidates at several spp, every caching method of the registry at a few values
of its equal-time knob and its comparison runs, each a stored run against the
same reference, timed in interleaved rounds (online training included in
seconds per frame). Prints the table (Pareto front marked, speed-up at equal
MRSE and FLIP with its bootstrap CI; docs/pareto.md) and the wall time.
Then runs the same call again on the same data folder: it reuses every
stored run and measures only the timing rounds; printed are its wall time
and its ratio to the first call's. ``--out`` also keeps pareto.json and the
two plots.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from jobs.protocol.ranges import parse_range


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--res", type=int, default=32)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--pt-spp", default="1,2,4,8,16")
    parser.add_argument("--knob-values", default="1,4,16",
                        help="values of every caching method's equal-time knob")
    parser.add_argument("--pretrain-frames", type=int, default=8)
    parser.add_argument("--ref-spp", type=int, default=1024)
    parser.add_argument("--timing-rounds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    from rich.console import Console

    from jobs.pareto.pareto import run_pareto
    from jobs.pareto.plan import ParetoSpec, knob_methods
    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from service.pareto_table import pareto_table

    knob_values = parse_range(args.knob_values, integer=True)
    spec = ParetoSpec(scene=args.scene, resolution=args.res, frames=args.frames,
                      seeds=args.seeds, pt_spp=parse_range(args.pt_spp, integer=True),
                      knob_values=dict.fromkeys(knob_methods(), knob_values),
                      pretrain_frames=args.pretrain_frames, ref_spp=args.ref_spp,
                      timing_rounds=args.timing_rounds)
    with tempfile.TemporaryDirectory() as folder:
        settings = Settings(data_dir=Path(folder))
        store = open_store(settings)
        walls = []
        for _ in range(2):      # the second call reuses every run the first stored
            start = time.perf_counter()
            result = run_pareto(spec, store, settings, out_dir=args.out)
            walls.append(time.perf_counter() - start)
        store.close()
    Console(width=220 if not sys.stdout.isatty() else None).print(pareto_table(result))
    print(f"{len(result.points)} points, {args.res}x{args.res}, {args.frames} frames x "
          f"K={args.seeds}, {args.timing_rounds} timing rounds: {walls[0]:.1f} s wall; "
          f"the same call again ({result.work['points_reused']} runs reused, "
          f"{result.work['points_rendered']} rendered): {walls[1]:.1f} s wall, "
          f"{walls[1] / walls[0]:.2f} of the first")


if __name__ == "__main__":
    main()
