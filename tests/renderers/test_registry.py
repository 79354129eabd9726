"""The method registry: each method declares itself, and jobs/service read only the registry."""

from __future__ import annotations

import importlib
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace

import pytest

from renderers.methods import (
    BASELINE,
    METHODS,
    MethodError,
    check_applies,
    equal_time_pairs,
    method_table,
    parse_params,
    series_label,
    sweep_methods,
)
from renderers.methods.base import Method, MethodParams

ROOT = Path(__file__).resolve().parents[2]


def test_reading_the_registry_does_not_import_mitsuba():
    """The service validates specs without Mitsuba: the registry, the spec models and
    the knobs must not import it (the integrators are imported when a render starts)."""
    code = ("import sys, renderers.methods, jobs.protocol.spec, jobs.protocol.calibration; "
            "from renderers.methods import METHODS; "
            "[m.knob for m in METHODS.values()]; "
            "assert 'mitsuba' not in sys.modules, 'mitsuba imported'")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_is_declared_by_its_own_module(name):
    method = METHODS[name]
    assert isinstance(method, Method) and method.name == name and method.description
    assert issubclass(method.params, MethodParams)
    module = importlib.import_module(method.render.__module__)
    assert module.__name__.startswith("renderers.methods.")
    parse_params(name, {})   # default parameters are valid


def test_readme_method_table_is_generated_from_the_registry():
    readme = (ROOT / "README.md").read_text()
    begin, end = "<!-- methods:begin -->\n", "\n<!-- methods:end -->"
    assert begin in readme and end in readme, "README.md lost the method-table markers"
    table = readme[readme.index(begin) + len(begin):readme.index(end)]
    assert table == method_table(), ("README.md's method table is stale: replace it with "
                                     "the output of `python -m renderers.methods`")
    for name, method in METHODS.items():
        assert f"| `{name}` | {method.description} |" in table


def test_knobs_keep_todays_candidates():
    assert METHODS[BASELINE].knob.name == "spp"
    assert list(METHODS[BASELINE].knob.candidates) == [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48,
                                                       64, 96, 128, 192, 256, 384, 512]
    nirc = METHODS["nirc"].knob
    assert nirc.name == "nc" and list(nirc.candidates) == [1, 2, 4, 8, 16, 32]
    assert nirc.usable({}) and not nirc.usable({"estimator": "unbiased"})
    assert nirc.apply({"nc": [8, 1], "x": 1}, 4) == {"nc": [4, 1], "x": 1}
    # the light-selection and direct-light methods calibrate spp, like PT; NRC has no knob
    assert [name for name, m in METHODS.items()
            if m.knob and m.knob.name == "nc"] == ["nirc", "nirc-nvc-env"]
    assert METHODS["nirc-nvc-env"].knob.candidates == nirc.candidates
    assert METHODS["nrc"].knob is None
    for name in ("pt-power", "pt-spatial", "nvc-lights", "nvc-env", "restir-di", "restir-nvc",
                 "neural-di", "nrc-di"):
        assert METHODS[name].knob.candidates == METHODS[BASELINE].knob.candidates


def test_sweep_roles_keep_todays_series_and_labels():
    from jobs.protocol.spec import SWEEP_METHODS, SweepSpec
    from jobs.sweeps.sweep import SERIES_LABELS

    assert sweep_methods() == SWEEP_METHODS == ("nirc", "nrc")
    assert SERIES_LABELS == {"nirc": "NIRC", "nrc": "NRC", "nirc-equal-time": "NIRC equal time"}
    assert series_label("NIRC biased BTH") == "NIRC biased BTH"
    assert equal_time_pairs(["nirc", "nrc"]) == equal_time_pairs(["nrc", "nirc"]) \
        == [("nirc", "nrc")]
    assert equal_time_pairs(["nirc"]) == []
    assert SweepSpec(scene="s", eps=[0.5]).nc_candidates() == [1, 2, 4, 8, 16, 32]
    with pytest.raises(ValueError, match="methods"):
        SweepSpec(scene="s", eps=[0.5], methods=["pt"])
    assert METHODS["nirc"].sweep.point(None) == {"estimator": "biased", "nc": [1, 1]}
    assert METHODS["nirc"].sweep.point(8) == {"estimator": "biased", "nc": [8, 1]}
    assert METHODS["nrc"].sweep.point(None) == {}


def _features(**values):
    base = dict(shape_count=3, emitter_count=2, area_emitter_count=2, has_envmap=True,
                has_many_lights=False, has_glossy=False, has_delta=False,
                polygon_emitter_count=2, animation_changes=())
    return SimpleNamespace(**{**base, **values})


#: Methods with a cache that are not caching methods (no ``build``): the visibility
#: caches of `nvc-lights` and `nvc-env` live on positions too (their other limits:
#: test_nvc_lights.py, test_nvc_env.py), as does `nirc-nvc-env`, whose two caches its
#: own build makes; `restir-di`, `restir-nvc`, `neural-di` and
#: `nrc-di` shade surface points (test_restir.py, test_neural_di.py, test_nrc_di.py), as
#: do the control variates at first hits (test_control_variates.py, test_ncv.py).
NEED_A_SURFACE = {"nvc-lights", "nvc-env", "nirc-nvc-env", "restir-di", "restir-nvc",
                  "neural-di", "nrc-di", "cv-sh", "cv-vmf", "ncv"}
#: Lighting each method needs besides (nvc-env: an environment map; restir-di: area
#: emitters only, so none).
ENVMAP = {"nvc-env": True, "nirc-nvc-env": True, "restir-di": False, "restir-nvc": False}


def test_applies_to_skips_caches_without_a_surface_and_nothing_else():
    for name, method in METHODS.items():
        assert method.applies_to(_features()) == (True, "")
        applies, reason = method.applies_to(_features(shape_count=0))
        assert applies == (method.build is None and name not in NEED_A_SURFACE), name
        assert applies or "surface" in reason
    with pytest.raises(MethodError, match="does not apply"):
        check_applies("nrc", _features(shape_count=0))


def test_every_method_applies_to_every_built_in_scene(mi):
    """Today's behaviour: no built-in scene is skipped by any method, except by
    `grid-cache` the scenes with glossy or delta BSDFs (its records have no direction),
    `nvc-lights` and `restir-nvc` the scenes with one emitter (nothing to select),
    by `nvc-env` and `nirc-nvc-env` those without an environment map, by `restir-di`, `restir-nvc` and
    `neural-di` the scene lit by an environment (`sky`) and by `neural-di` the scene with
    300 lights (one cache output per light)."""
    from renderers.scenes import load_scene
    from renderers.scenes.library import builtin_names

    for scene_name in builtin_names():
        features = load_scene(scene_name, 8).features
        for name in METHODS:
            if name in ("nvc-lights", "restir-nvc") and features.emitter_count == 1:
                assert METHODS[name].applies_to(features) == \
                    (False, "one emitter: nothing to select")
            elif name in ("nvc-env", "nirc-nvc-env") and not features.has_envmap:
                assert METHODS[name].applies_to(features) == (False, "no environment map")
            elif name in ("restir-di", "restir-nvc") and features.has_envmap:
                assert METHODS[name].applies_to(features) == \
                    (False, "an environment emitter: restir-di samples points on area "
                            "emitters only")
            elif name == "grid-cache" and (features.has_glossy or features.has_delta):
                applies, reason = METHODS[name].applies_to(features)
                assert not applies and "diffuse surfaces only" in reason, scene_name
            elif name == "neural-di" and features.emitter_count > 32:
                assert METHODS[name].applies_to(features) == \
                    (False, "more than 32 emitters: one cache output per light")
            elif name == "neural-di" and features.has_envmap:
                assert METHODS[name].applies_to(features) == \
                    (False, "an emitter that is not a polygon (environment, delta or curved "
                            "area light): neural-di's unshadowed term is a polygon integral")
            else:
                check_applies(name, features)


def test_integrators_receive_the_validated_model(mi):
    """The method's parameter model reaches the integrator as typed values (no text)."""
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 8)
    params = parse_params("nirc", {"termination": "adaptive", "nc": [8, 1], "sph_c": 0.02})
    integrator, trainer, _cache = METHODS["nirc"].build(scene, params, 0)
    policy = integrator.policy
    assert (integrator.estimator, policy.name, integrator.nc, policy.settings.sph_c,
            policy.settings.nc) == ("biased", "adaptive", [8, 1], 0.02, (8, 1))
    assert trainer.key_vertex == "departure"
    params = parse_params("nrc", {"unbiased_every": 4, "termination": "adaptive"})
    integrator, trainer, _cache = METHODS["nrc"].build(scene, params, 0)
    assert integrator.policy.name == "adaptive" and trainer.unbiased_every == 4
    assert trainer.key_vertex == "arrival"


def test_the_integrator_takes_its_parameters_only_from_the_methods_model(mi):
    """The estimator's parameters are parsed once, by the method's model, and reach
    the plugin through configure(); an unconfigured plugin refuses to render."""
    from renderers.integrators import nirc, register_plugins

    register_plugins()
    loaded = mi.load_dict({"type": nirc.NIRC_PLUGIN})
    loaded.configure(parse_params("nirc", {"estimator": "unbiased", "nc": [3, 1, 1]}))
    assert loaded.nc == [3, 1, 1] and loaded.estimator == "unbiased"
    with pytest.raises(MethodError, match="biased estimator takes one N_c"):
        parse_params("nirc", {"nc": [4, 2]})
    unconfigured = mi.load_dict({"type": nirc.NIRC_PLUGIN})
    scene = mi.load_dict(mi.cornell_box())
    with pytest.raises(Exception) as refused:   # mi.render wraps the error it raised
        mi.render(scene, integrator=unconfigured, spp=1)
    chain, error = [], refused.value
    while error is not None:
        chain.append(str(error))
        error = error.__cause__ or error.__context__
    assert any("configure" in message for message in chain), chain


def fake_report_execute(monkeypatch) -> list:
    """Replace the report's executor by one answering at once (the strongest PT at equal
    time is pt-power; a calibrated PT takes 3 spp); the jobs' (method, params, spp, time
    budget) are appended to the list returned."""
    import jobs.pareto.report as report_module
    from jobs.protocol.results import RunResultDetail

    calls = []

    def fake_execute(job, store, settings, progress=None):
        spec = job.spec
        calls.append((spec.method, dict(spec.params), spec.spp,
                      spec.time_budget and spec.time_budget.model_dump(exclude_defaults=True)))
        mrse = 0.5 if spec.method == "pt-power" else 1.0    # the strongest PT at equal time
        metrics = {"mrse_mean": mrse, "flip_hdr_mean": 0.1}
        if spec.time_budget is not None:
            metrics["calibration"] = {"chosen": 8, "fits": True}
        spp = 3 if spec.time_budget is not None and spec.method == "pt" else spec.spp
        timings = {"seconds_per_frame": 0.01, "stages": {}}
        result = RunResultDetail(
            id=len(calls), created_at=datetime.now(UTC), scene="s", scene_fingerprint="f",
            method=spec.method, params=dict(spec.params), resolution=[64, 64], spp=spp,
            frames=1, seeds=1, seconds_per_frame=0.01, device_key="dev", quality={},
            estimator_version=1, metric_version=1, current=True, mrse=mrse, flip=0.1,
            metrics=metrics, timings=timings, path_stats={}, device={}, versions={},
            git_commit=None, reference_id=None, per_seed=[])
        return SimpleNamespace(metrics=metrics, timings=timings, run_id=len(calls),
                               spec=spec.model_copy(update={"spp": spp}),
                               device={"device_key": "dev"}, result=result)

    monkeypatch.setattr(report_module, "execute", fake_execute)
    return calls


def test_comparison_report_runs_todays_fig7_protocol(monkeypatch):
    """The report reads its runs from the registry; runs, labels and rows are today's."""
    import jobs.pareto.report as report_module

    calls = fake_report_execute(monkeypatch)
    report = report_module.comparison_report("s", None, None, max_depth=8, pretrain_frames=7)
    cache = {"max_depth": 8, "pretrain_frames": 7}
    at_time = [("pt", {"max_depth": 8}, 1, {"ms": 10.0}),
               *((name, {"max_depth": 8, "rr_mode": "throughput"}, 1, {"ms": 10.0})
                 for name in ("pt", "pt-power", "pt-spatial"))]
    assert calls == [
        ("pt", {"max_depth": 8}, 1, None), ("pt", {"max_depth": 8}, 2, None),
        ("nrc", cache, 1, None),
        ("nirc", {**cache, "estimator": "biased", "nc": [4]}, 1, None),
        ("nirc", {**cache, "estimator": "unbiased", "nc": [3, 1, 1]}, 1, None),
        ("grid-cache", {"max_depth": 8}, 1, None),
        ("nirc", {**cache, "estimator": "biased"}, 1,
         {"pt_spp": 2, "candidates": [1, 2, 4, 8, 16, 32]}),
        *at_time, *at_time, *at_time]
    assert [row.label for row in report.equal_spp] == [
        "paper's PT 1 spp", "paper's PT 2 spp", "NRC biased", "NIRC biased (N_c 4)", "NIRC unbiased (N_c 3,1,1)",
        "Grid cache (var-bound)"]
    assert [row.label for row in report.equal_time] == [
        "paper's PT 2 spp (budget)", "NIRC biased (N_c 8)",
        *(row for method in ("NRC", "NIRC unbiased", "Grid cache")
          for row in (method, f"paper's PT 3 spp (= {method} time)",
                      f"strongest PT: pt-power 1 spp (= {method} time)"))]
    assert report.device == "dev" and report.skipped == []
    assert [row.id for row in report.equal_spp] == [1, 2, 3, 4, 5, 6]   # the runs' own results
    assert report.bounds == {"max_pt_spp": None, "strongest": ["pt", "pt-power", "pt-spatial"],
                             "runs": ["PT 1 spp", "PT 2 spp", "NRC", "NIRC biased",
                                      "NIRC unbiased", "Grid cache", "NIRC biased (equal time)"],
                             "pt_at": ["NRC", "NIRC unbiased", "Grid cache"]}


@pytest.mark.parametrize("honoured", [True, False])
def test_comparison_report_bounds_its_pt_calibrations(monkeypatch, honoured):
    """max_pt_spp and strongest bound the PT calibrations: each equal-time PT job tries
    no spp above the ceiling, and only the named strongest-PT candidates are calibrated.
    Planted defect (honoured=False): a report passing the bounds to nothing calibrates
    more, which the same check rejects."""
    import jobs.pareto.report as report_module

    calls = fake_report_execute(monkeypatch)
    if not honoured:
        real = report_module.comparison_report
        monkeypatch.setattr(report_module, "comparison_report",
                            lambda *args, max_pt_spp=None, strongest=None, **kwargs:
                            real(*args, **kwargs))
    report = report_module.comparison_report("s", None, None, max_pt_spp=6,
                                             strongest=("pt-power",))
    at_time = [(method, params, budget) for method, params, _spp, budget in calls
               if budget is not None and "ms" in budget]
    within = (len(at_time) == 3 * 2       # per matched method: the paper's PT, pt-power
              and [method for method, params, _ in at_time] == ["pt", "pt-power"] * 3
              and all(budget["candidates"] == [1, 2, 3, 4, 6] for *_, budget in at_time))
    assert within == honoured, at_time
    if honoured:
        assert (report.bounds["max_pt_spp"], report.bounds["strongest"]) == (6, ["pt-power"])
        assert "strongest PT: pt-power 1 spp (= NRC time)" in [r.label for r in report.equal_time]
        with pytest.raises(ValueError, match="strongest: give any of pt, pt-power"):
            report_module.comparison_report("s", None, None, strongest=("nrc",))


@pytest.mark.parametrize("honoured", [True, False])
def test_comparison_report_renders_only_the_runs_asked_for(monkeypatch, honoured):
    """runs leaves comparison runs unrendered and pt_at calibrates PT only at the named
    matched runs' times (no strongest PT: the paper's PT alone); a run the budget needs,
    or an unknown label, is refused. Planted defect (honoured=False): a report ignoring
    runs and pt_at renders and calibrates more, which the same check rejects."""
    import jobs.pareto.report as report_module

    calls = fake_report_execute(monkeypatch)
    if not honoured:
        real = report_module.comparison_report
        monkeypatch.setattr(report_module, "comparison_report",
                            lambda *args, runs=None, pt_at=None, **kwargs: real(*args, **kwargs))
    report = report_module.comparison_report(
        "s", None, None, runs=("PT 1 spp", "PT 2 spp", "NRC", "NIRC unbiased"),
        pt_at=("NIRC unbiased",), strongest=())
    rendered = [(method, spp) for method, _params, spp, budget in calls if budget is None]
    at_time = [method for method, _params, _spp, budget in calls
               if budget is not None and "ms" in budget]
    asked = (rendered == [("pt", 1), ("pt", 2), ("nrc", 1), ("nirc", 1)]
             and at_time == ["pt"]
             and all(budget is None or "ms" in budget for *_, budget in calls))
    assert asked == honoured, (rendered, at_time)
    if honoured:
        assert [row.label for row in report.equal_time] == [
            "NIRC unbiased", "paper's PT 3 spp (= NIRC unbiased time)"]
        assert report.bounds["pt_at"] == ["NIRC unbiased"]
        for bad in ({"runs": ("PT 1 spp", "NRC")}, {"runs": ("PT 2 spp", "no-such")},
                    {"runs": ("PT 2 spp", "NRC"), "pt_at": ("Grid cache",)}):
            with pytest.raises(ValueError, match="runs: give|pt_at: give"):
                report_module.comparison_report("s", None, None, **bad)


def test_every_cache_override_field_is_checked_at_parse_time():
    """Each method's cache-override fields build their preset when parsed: a field the
    preset does not have is refused, naming it (service: 422 at submission)."""
    for name, method in METHODS.items():
        fields = [f for f in method.params.model_fields if f.endswith("cache")]
        for field in fields:
            with pytest.raises(MethodError, match=f"{field}: unknown cache config field"):
                parse_params(name, {field: {"no_such_setting": 1}})
        # The control variates' model overrides (``sh``, ``vmf``, ``ncv``):
        # test_control_variates.py, test_ncv.py.
        assert bool(fields) == (name not in ("pt", "pt-power", "pt-spatial", "restir-di",
                                             "cv-sh", "cv-vmf", "ncv")), name


def test_checking_cache_overrides_does_not_import_mitsuba():
    """The service validates submissions without loading the renderer."""
    code = ("import sys; from renderers.methods import parse_params; "
            "parse_params('nirc', {'cache': {'preset': 'small'}}); "
            "print('mitsuba' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True, cwd=Path(__file__).parents[2])
    assert result.stdout.strip() == "False"


def test_every_parameter_of_a_built_in_method_says_what_it_is():
    """`nirc-bench methods NAME` shows each parameter's description as its help: none is
    left blank. Planted: a model with a field without a description is caught."""
    from pydantic import Field

    from renderers.methods import BUILTIN, MethodParams
    from service.method_info import method_info

    def unexplained(model: type) -> list[str]:
        return [name for name, field in model.model_fields.items()
                if not (field.description or "").strip()]

    missing = {name: unexplained(method.params) for name, method in BUILTIN.items()}
    assert not any(missing.values()), missing
    helps = {p["name"]: p["help"] for p in method_info("nirc")["params"]}
    assert "Eq. 13" in helps["estimator"] and "throughput" in helps["rr_mode"]

    class Planted(MethodParams):
        said: int = Field(1, description="a count")
        unsaid: int = 2

    assert unexplained(Planted) == ["unsaid"]


def test_discovery_imports_every_module_but_the_skipped_and_private(tmp_path, monkeypatch):
    """Adding a plugin is adding a module: discovery imports each public module of the
    package, in name order, and none it is told to skip."""
    from renderers.registry import Registry, discover

    package = tmp_path / "toy_plugins"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name in ("b_second", "a_first", "_private", "helper"):
        (package / f"{name}.py").write_text(
            "import builtins\nbuiltins.TOY_REGISTRY.register(__name__.rsplit('.', 1)[1])\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry = Registry("toys", lambda name: name)
    monkeypatch.setattr("builtins.TOY_REGISTRY", registry, raising=False)
    discover("toy_plugins", [str(package)], skip=("helper",))
    assert list(registry) == ["a_first", "b_second"]


def test_a_registry_refuses_two_plugins_of_one_name():
    from renderers.registry import Registry

    registry = Registry("methods", lambda method: method.name)
    first, twin = SimpleNamespace(name="pt"), SimpleNamespace(name="pt")
    assert registry.register(first) is first and registry.register(first) is first
    with pytest.raises(ValueError, match="two methods are named 'pt'"):
        registry.register(twin)


def test_the_integrator_plugins_keep_their_names(mi):
    """Every integrator class registers itself under the Mitsuba plugin name the methods
    and stored scene descriptions load it by; each loads after register_plugins()."""
    from renderers.integrators import PLUGINS, register_plugins

    register_plugins()
    assert sorted(PLUGINS) == [
        "nirc_control_variate", "nirc_grid_cache", "nirc_grid_update", "nirc_neural_di", "nirc_nirc",
        "nirc_nirc_nvc_env", "nirc_nrc", "nirc_nrc_di", "nirc_nvc_env", "nirc_path",
        "nirc_residual_probe", "nirc_training_nrcselftrainingintegrator", "nirc_training_trainingpathintegrator"]
    assert all(cls.plugin_name == name for name, cls in PLUGINS.items())
    assert type(mi.load_dict({"type": "nirc_path"})) is PLUGINS["nirc_path"]
