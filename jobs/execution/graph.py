"""A sweep as a task graph: its reference first, then the caches, then the points.

A sweep (jobs/sweeps/sweep.py) is a chain of content-keyed steps, each of which only
needs what earlier steps stored: the reference; per method and seed a trained
cache with its converged cache-at-v1 image (a snapshot); per method the eps
points, which need every seed's snapshot; finally the sweep job itself, which
adds the "NIRC equal time" series (it needs both methods' points), the plots
and the sweep row, re-using everything else. For a parameter sweep (the N_c sweep
among them) the points only need the reference.

Each step is a *stage* job in the database (kind ``stage``, ``parent_id`` the
sweep's job), so it is queued, isolated, retried and resumed like any job, and
:class:`jobs.execution.dispatch.Dispatcher` submits the stages to Dask with these
dependencies: independent stages (the caches of different seeds, the points
of different methods) run on different workers at once. A stage only stores
what the sweep would otherwise make itself, so the sweep's result is the
same whether its stages ran first or not (tested).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from jobs.protocol.spec import SweepSpec


@dataclass(frozen=True)
class Stage:
    """One step of a sweep: ``name`` is unique within the sweep; ``after`` names the
    stages it needs; ``task`` says what to run (jobs.sweeps.sweep.run_stage)."""

    name: str
    task: dict[str, Any]
    after: tuple[str, ...] = ()


def sweep_stages(spec: SweepSpec) -> list[Stage]:
    """The stages of ``spec`` in an order where every stage follows those it needs."""
    stages = [Stage("reference", {"stage": "reference"})]
    if spec.kind == "parameter":
        assert spec.parameter is not None
        return stages + [Stage(f"{method} {spec.parameter.name}={value}",
                               {"stage": "parameter-point", "method": method, "value": value},
                               ("reference",))
                         for method in spec.methods for value in spec.parameter.values]
    for method in spec.methods:
        caches = [Stage(f"{method} cache {seed + 1}/{spec.seeds}",
                        {"stage": "snapshot", "method": method, "seed": seed}, ("reference",))
                  for seed in range(spec.seeds)]
        stages += caches
        stages.append(Stage(f"{method} points", {"stage": "series", "method": method},
                            tuple(cache.name for cache in caches)))
    return stages


def final_stages(stages: list[Stage]) -> list[Stage]:
    """The stages no other stage needs: the sweep job itself runs after these."""
    needed = {name for stage in stages for name in stage.after}
    return [stage for stage in stages if stage.name not in needed]
