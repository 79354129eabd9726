"""The measured counterpart of the variance-trading paper's Table 1 (docs/variance_trading.md):
`grid-cache` with each policy and plain `pt` on door, corridor and cornell-box, every
point a run of the generic parameter sweep (jobs/sweeps/sweep.py), the policies'
parameters swept by their dotted names. Prints a Markdown table.

    .venv/bin/python scripts/variance_trading_table.py --res 64 --frames 4 --seeds 2 \\
        --prefill 32 --data /tmp/vtt-data

Columns: MSE, rVar and rBias^2 (noise-corrected) of the K renders of F 1-spp frames;
the paper's path length (vertices up to the termination vertex, the blended segment
by its weight: ``weighted_length``) beside the project's average surface vertices
per path; kernel milliseconds per frame of the render (tracer) and propagation stages.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

#: (label, policy, swept parameter, values, fixed policy parameters)
SERIES: tuple[tuple[str, str, str, list[Any], dict[str, Any]], ...] = (
    ("Var. bound (abs.)", "var-bound", "threshold", [0.01, 0.1, 1.0, 10.0], {"relative": False}),
    ("Var. bound (rel.)", "var-bound", "threshold", [0.01, 0.1, 1.0, 10.0], {"relative": True}),
    ("MSE min.", "mse-min", "samples", [10.0, 100.0, 1000.0], {}),
    ("Area-spread", "area-spread", "c", [0.01, 100.0], {}),
)
SCENES = ("door", "corridor", "cornell-box")


def fmt(value: Any, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}g}"


def main() -> None:
    from jobs.protocol.spec import ParameterSweep, ReferenceSpec, SweepSpec
    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.sweeps.sweep import run_sweep

    parser = argparse.ArgumentParser()
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--prefill", type=int, default=32)
    parser.add_argument("--ref-spp", type=int, default=1024)
    parser.add_argument("--rr-survival", type=float, default=0.9)
    parser.add_argument("--data", type=Path, default=Path("data"))
    parser.add_argument("--scenes", default=",".join(SCENES))
    args = parser.parse_args()

    settings = Settings(data_dir=args.data)
    store = open_store(settings)
    common = dict(resolution=args.res, seeds=args.seeds, frames=args.frames,
                  reference=ReferenceSpec(spp=args.ref_spp))
    lines = ["| scene | method | MSE | rVar | rBias² | path length (paper) | "
             "vertices / path | tracer ms (kernels) | propagation ms (kernels) |",
             "|---|---|---|---|---|---|---|---|---|"]

    def row(scene: str, label: str, run_id: int) -> str:
        run = store.get_run(run_id)
        m, stats = run.metrics, run.path_stats
        # Kernel time: the stages' device work, without the host's tracing of the
        # (not frozen) render loop, which dominates small frames on this CPU.
        parts = (run.timings.get("breakdown") or {}).get("kernel_parts_s") or {}
        length = stats.get("weighted_length", stats.get("avg_path_vertices"))
        return (f"| {scene} | {label} | {fmt(m.get('mse_mean'))} | {fmt(m.get('rvar'))} | "
                f"{fmt(m.get('rbias2'))} | {fmt(length, 3)} | "
                f"{fmt(stats.get('avg_path_vertices'), 3)} | "
                f"{fmt(1e3 * parts['render'] if 'render' in parts else None)} | "
                f"{fmt(1e3 * parts['propagation'] if 'propagation' in parts else None)} |")

    try:
        for scene in args.scenes.split(","):
            spec = SweepSpec(scene=scene, methods=["pt"], **common,
                             parameter=ParameterSweep(name="rr_survival",
                                                      values=[args.rr_survival]))
            result = run_sweep(spec, store, settings)
            lines.append(row(scene, f"PT (rr {args.rr_survival})", result.rows[0].id))
            for label, policy, name, values, fixed in SERIES:
                spec = SweepSpec(
                    scene=scene, methods=["grid-cache"], **common,
                    parameter=ParameterSweep(name=f"termination_params.{name}", values=values),
                    params={"termination": policy, "termination_params": fixed,
                            "prefill_frames": args.prefill, "rr_survival": args.rr_survival})
                result = run_sweep(spec, store, settings)
                for point in result.rows:
                    lines.append(row(scene, f"{label} ({name} = {point.value:g})", point.id))
                print("\n".join(lines[-len(result.rows):]), flush=True)
    finally:
        store.close()
    print("\n".join(lines))


if __name__ == "__main__":
    main()
