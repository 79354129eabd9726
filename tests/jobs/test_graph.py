"""A sweep's task graph: which stages exist and what each needs."""

from __future__ import annotations

from jobs.execution.graph import final_stages, sweep_stages
from jobs.protocol.spec import SweepSpec


def _spec(**values) -> SweepSpec:
    return SweepSpec(**{"scene": "cornell-box", "seeds": 3, "eps": [0.1, 1.0], **values})


def test_eps_sweep_stages_reference_then_caches_then_points():
    stages = sweep_stages(_spec())
    names = [stage.name for stage in stages]
    assert names[0] == "reference" and len(names) == len(set(names)) == 1 + 2 * (3 + 1)
    by_name = {stage.name: stage for stage in stages}
    for method in ("nirc", "nrc"):
        caches = [f"{method} cache {seed}/3" for seed in (1, 2, 3)]
        for cache in caches:
            assert by_name[cache].after == ("reference",)
            assert by_name[cache].task["method"] == method
        assert by_name[f"{method} points"].after == tuple(caches)
    assert {s.name for s in final_stages(stages)} == {"nirc points", "nrc points"}


def test_every_stage_follows_the_stages_it_needs():
    for spec in (_spec(), _spec(methods=["nrc"], seeds=2), _spec(eps=None, nc=[1, 4, 8])):
        seen: set[str] = set()
        for stage in sweep_stages(spec):
            assert set(stage.after) <= seen, stage
            seen.add(stage.name)


def test_nc_sweep_points_need_only_the_reference():
    stages = sweep_stages(_spec(eps=None, nc=[1, 4]))
    assert [(s.name, s.after) for s in stages[1:]] == [("nirc nc=1", ("reference",)),
                                                        ("nirc nc=4", ("reference",))]
    assert [s.task for s in stages[1:]] == [
        {"stage": "parameter-point", "method": "nirc", "value": nc} for nc in (1, 4)]
    assert [s.name for s in final_stages(stages)] == ["nirc nc=1", "nirc nc=4"]
