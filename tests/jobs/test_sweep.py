"""The adaptive equal-bias sweep (NIRC paper Sec. 6.3): masks, statistics, reuse, plots.

One small sweep (16x16, K = 2, 3 thresholds, a few training frames) is run once per
module; the tests read its stored result. What they check does not depend on how
well the tiny caches are trained: masks grow with eps, % IR bounces falls, the
rBias^2 of NIRC grows with its mask, and nothing is rendered twice.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from jobs.protocol.spec import ParameterSweep, ReferenceSpec, SweepSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.sweeps.sweep import (
    avg_path_length_authors,
    ir_bounces_pct,
    ir_bounces_pct_authors,
    run_sweep,
    v1_mask,
)
from renderers.integrators.termination import policy_params

SMALL = {"cache": {"batch_size": 1024}, "min_train_paths": 1024}


def small_spec(**overrides) -> SweepSpec:
    """A small sweep whose equal-time probes count on a loaded machine (the tests check
    what is recorded, not the machine's quiet: the test machine is shared)."""
    values = dict(scene="cornell-box", resolution=16, seeds=2, train_frames=4, v1_spp=32,
                  eps=[0.1, 0.3, 1.0], nc=[1, 2], params=SMALL, probe_frames=1,
                  reference=ReferenceSpec(spp=256), allow_loaded=True)
    return SweepSpec(**{**values, **overrides})


# ---- Pure functions -------------------------------------------------------------

@settings(max_examples=50, deadline=None)
@given(bias=arrays(np.float64, (6, 5), elements=st.floats(0, 3) | st.just(np.nan)),
       thresholds=st.lists(st.floats(0.01, 3), min_size=2, max_size=6))
def test_masks_are_monotone_in_eps(bias, thresholds):
    masks = [v1_mask(bias, eps) for eps in sorted(thresholds)]
    for smaller, larger in zip(masks, masks[1:], strict=False):
        assert not np.any(smaller & ~larger)   # a larger eps never drops a pixel
    assert not np.any(masks[-1] & np.isnan(bias))


def test_ir_bounces_from_cache_depth_fractions():
    assert ir_bounces_pct({"0": 0.5, "1": 0.5}) == 0.0
    assert ir_bounces_pct({"1": 0.25, "2": 0.75}) == pytest.approx(75.0)
    assert ir_bounces_pct({"1": 0.5, "3": 0.5}) == pytest.approx(100.0)  # v3: 2 bounces
    assert ir_bounces_pct({"0": 1.0}) is None and ir_bounces_pct(None) is None


def test_authors_average_path_length_from_the_histogram_and_the_background():
    # Half background, a quarter never used the cache (s = 1), a quarter used it at v2.
    fractions = {"0": 0.75, "2": 0.25}
    assert avg_path_length_authors(fractions, 0.5) == pytest.approx(0.25 * 1 + 0.25 * 2)
    assert ir_bounces_pct_authors(fractions, 0.5) == pytest.approx(50.0)  # (0 + 1) / 2
    # Today's figure counts only the invoking paths: 100 %.
    assert ir_bounces_pct(fractions) == pytest.approx(100.0)
    # No background: every path counts, s = 1 for those without a cache query.
    fractions = {"0": 0.2, "1": 0.5, "3": 0.3}
    assert avg_path_length_authors(fractions, 0.0) == pytest.approx(0.2 + 0.5 + 0.9)
    assert ir_bounces_pct_authors(fractions, 0.0) == pytest.approx(100 * (1.6 - 1))
    assert ir_bounces_pct(fractions) == pytest.approx(100 * 0.6 / 0.8)
    # All background: length 0, no foreground to take a percentage over.
    assert avg_path_length_authors({"0": 1.0}, 1.0) == 0.0
    assert ir_bounces_pct_authors({"0": 1.0}, 1.0) is None
    assert avg_path_length_authors(fractions, None) is None   # runs without the count


@pytest.mark.parametrize("values, fragment", [
    ({"eps": None, "nc": None}, "eps values"),
    ({"eps": [0.0, 0.5]}, "(0, 100]"),
    ({"nc": [0]}, "1..256"),
    ({"eps": []}, "give at least one eps value"),     # not 'must be in (0, 100]'
    ({"nc": []}, "give at least one nc value"),
    ({"methods": []}, "at least one method"),
    ({"methods": ["pt"]}, "nirc"),
    ({"seeds": 1}, "greater than or equal to 2"),
])
def test_bad_sweep_specs_are_explained(values, fragment):
    with pytest.raises(ValueError, match=fragment.replace("(", r"\(").replace("]", r"\]")
                       .replace("[", r"\[").replace(".", r"\.")):
        small_spec(**values)


# ---- A real (small) sweep ---------------------------------------------------------

@pytest.fixture(scope="module")
def sweep_env(tmp_path_factory, mi):
    """A small sweep, run as from the CLI under a user's usual umask (022)."""
    settings_ = Settings(data_dir=Path(tmp_path_factory.mktemp("sweep")) / "data")
    store = open_store(settings_)
    umask = os.umask(0o022)
    try:
        first = run_sweep(small_spec(), store, settings_)
    finally:
        os.umask(umask)
    yield settings_, store, first
    store.close()


def _series(result, name):
    return [row for row in result.rows if row.series == name]


def test_every_sweep_point_is_timed_after_a_warm_up_of_its_own(sweep_env):
    """A new mask makes Dr.Jit trace and record the frozen frame anew: every eps point's
    seeds warm up before their timed frames (the later eps of a series had none, and
    their first frames held the recording: 100-200 ms against 3-15 ms)."""
    settings_, store, result = sweep_env
    for row in result.rows:
        for seed in store.get_run(row.id).seed_results:
            assert seed.timings["warmup_frames"] >= 1, (row.series, row.eps, seed.seed)


def test_sweep_reports_every_series_and_point(sweep_env):
    _, _, result = sweep_env
    assert result.skipped == []
    for name in ("NIRC", "NRC", "NIRC equal time"):
        rows = _series(result, name)
        assert [row.eps for row in rows] == [0.1, 0.3, 1.0]
        for row in rows:
            assert row.finite
            for key in ("mrse", "flip", "ms_frame", "rbias2", "rvar", "avg_path_length",
                        "ir_bounces_pct", "avg_path_length_authors", "ir_bounces_pct_authors"):
                assert getattr(row, key) is not None and np.isfinite(getattr(row, key)), (name, key)
        # s <= the path's vertex count for every pixel; the camera of cornell-box sees
        # some background through the box's open side (s = 0 there).
        for row in rows:
            foreground = 1 - row.background_pct / 100
            assert 0 < row.background_pct < 20
            assert row.avg_path_length_authors <= row.avg_path_length + 1e-9
            assert row.avg_path_length_authors == pytest.approx(
                foreground * (1 + row.ir_bounces_pct_authors / 100))
    for row in _series(result, "NIRC equal time"):
        calibration = row.calibration
        assert calibration["knob"] == "nc" and calibration["chosen"] == row.nc
        # Every candidate timed in 3 rounds, each round after a re-measured NRC budget.
        assert set(calibration["measured_s"]) == {"1", "2"} and calibration["rounds"] == 3
        assert calibration["order"][::3] == ["budget"] * 3
        assert row.calibration_capped == (calibration["chosen"] == 2)
        assert row.calibration_unstable == calibration["unstable"]
    work = result.work
    assert work["reference_rendered"] == 1 and work["snapshots_trained"] == 4
    assert work["points_rendered"] >= 6 and work["calibrations"] == 3


def test_masks_grow_and_ir_bounces_fall_with_eps(sweep_env):
    _, _, result = sweep_env
    for name in ("NIRC", "NRC"):
        rows = _series(result, name)
        masks = [row.mask_pct for row in rows]
        v1 = [row.cache_at_v1_pct for row in rows]
        ir = [row.ir_bounces_pct for row in rows]
        assert masks == sorted(masks) and v1 == sorted(v1), name
        # Every eps renders with the same random numbers, so paths differ only where a
        # larger mask lets them stop at v1: the % IR bounces cannot rise.
        assert all(b <= a + 1e-9 for a, b in zip(ir, ir[1:], strict=False)), (name, ir)
        assert ir[0] > ir[-1], (name, ir)


def test_masks_use_the_noise_corrected_bias_of_the_snapshots(sweep_env):
    """The rows' mask coverage is that of the noise-corrected map of the stored v1 images
    and variances; on these 32-spp images the raw map would admit fewer pixels."""
    from jobs.protocol.executor import prepare
    from jobs.protocol.job import RenderJob
    from jobs.sweeps.snapshots import _load
    from metrics.bias_maps import bias_map, passes

    settings_, store, result = sweep_env
    spec = small_spec()
    reference = prepare(RenderJob.parse(spec.base_render_spec()), store, settings_).reference
    gained = 0
    for name in ("NIRC", "NRC"):
        for row in _series(result, name):
            run = store.get_run(row.id)
            corrected, raw = [], []
            for key in run.metrics["sweep"]["snapshots"]:
                snap = _load(store.find_snapshot(key), settings_)
                assert snap.v1_variance.shape == snap.v1_image.shape
                assert np.all(snap.v1_variance >= 0) and np.any(snap.v1_variance > 0)
                args = (snap.v1_image, reference.mean, spec.metric_eps)
                corrected.append(passes(bias_map("relative-mse", *args,
                                                 v_variance=snap.v1_variance,
                                                 ref_variance=reference.variance),
                                        row.eps).mean())
                raw.append(passes(bias_map("relative-mse", *args), row.eps).mean())
            assert row.mask_pct == pytest.approx(100 * np.mean(corrected)), (name, row.eps)
            gained += np.mean(corrected) > np.mean(raw)
    assert gained > 0


def test_points_are_stored_with_seeds_snapshots_and_convergence(sweep_env):
    _, store, result = sweep_env
    run = store.get_run(_series(result, "NRC")[0].id)
    assert run.params["termination"] == "adaptive" and run.seeds == 2
    assert len(run.seed_results) == 2
    assert len(run.metrics["sweep"]["snapshots"]) == 2
    curve = run.seed_results[0].metrics["convergence"]
    assert len(curve["frame_mrse"]) == run.frames == 1
    # Each seed's frames were collected for the per-cache statistics; one frame per
    # seed is too few for a per-cache variance, and the run says so.
    reason = run.metrics["per_cache_unavailable"]
    assert run.metrics["rbias2_per_cache_mean"] is None and "no per-frame" not in reason
    snapshot = store.find_snapshot(run.metrics["sweep"]["snapshots"][0])
    assert {a.kind for a in snapshot.artifacts} == {"cache_weights", "v1_image", "v1_variance"}
    assert snapshot.stats["v1_passes"] >= 2 and snapshot.stats["v1_spp_rendered"] >= 32
    assert len(snapshot.stats["convergence"]["frame_mrse"]) == 4


def test_a_snapshot_stored_without_its_variance_is_not_loaded(sweep_env):
    """Snapshots made before the v1 variance was stored fail to load with the KeyError
    that get_or_make_snapshot answers by making the snapshot again."""
    from types import SimpleNamespace

    from jobs.sweeps.snapshots import _load

    settings_, store, result = sweep_env
    row = store.find_snapshot(result.snapshots[0].key)
    assert _load(row, settings_).v1_variance.shape == (16, 16, 3)
    old = SimpleNamespace(key=row.key, id=row.id, stats=row.stats,
                          artifacts=[a for a in row.artifacts if a.kind != "v1_variance"])
    with pytest.raises(KeyError):
        _load(old, settings_)


def test_plots_are_written_and_referenced_from_the_database(sweep_env):
    _, store, result = sweep_env
    for name in ("fig13", "fig10", "result"):
        assert Path(result.files[name]).stat().st_size > 0
    # Its folder, data/sweeps/sweep-<id>, is owner-only as the data folder is (it was
    # created world-readable under the umask).
    folder = Path(result.files["result"]).parent
    for created in (folder, folder.parent):
        assert stat.S_IMODE(created.stat().st_mode) == 0o700, created
    row = store.get_sweep(result.sweep_id)
    assert row.status == "succeeded" and row.result["rows"] == result.to_json()["rows"]
    assert {a.kind for a in row.artifacts} == {"fig13", "fig10"}


def test_a_second_identical_sweep_renders_nothing(sweep_env):
    settings_, store, first = sweep_env
    second = run_sweep(small_spec(), store, settings_)
    assert second.sweep_id == first.sweep_id
    assert second.work == {"reference_rendered": 0, "snapshots_trained": 0,
                           "snapshots_reused": 4, "points_rendered": 0, "points_reused": 9,
                           "calibrations": 0}
    assert [r.id for r in second.rows] == [r.id for r in first.rows]
    assert second.snapshots == first.snapshots   # the re-drawn plots show every cache


def test_a_new_eps_reuses_the_caches(sweep_env):
    settings_, store, _ = sweep_env
    result = run_sweep(small_spec(eps=[0.1, 0.3, 0.5, 1.0], equal_time=False), store,
                       settings_)
    assert result.work["snapshots_trained"] == 0 and result.work["snapshots_reused"] == 4
    assert result.work["points_rendered"] == 2 and result.work["points_reused"] == 6


MIRROR_XML = """\
<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/></transform>
        <bsdf type="conductor"/>
    </shape>
</scene>
"""


def test_a_scene_without_usable_first_vertices_is_skipped_with_a_reason(tmp_path, mi):
    """A camera that sees only a perfect mirror: no path can use a cache at v1."""
    scene = tmp_path / "mirror.xml"
    scene.write_text(MIRROR_XML)
    settings_ = Settings(data_dir=tmp_path / "data")
    store = open_store(settings_)
    result = run_sweep(small_spec(scene=str(scene), resolution=8, train_frames=2, v1_spp=4,
                                  eps=[0.5]), store, settings_)
    assert result.rows == []
    reasons = {s.method: s.reason for s in result.skipped}
    assert set(reasons) == {"nirc", "nrc", "nirc-equal-time"}
    assert "first vertex" in reasons["nirc"]
    store.close()


# ---- The sweep as a task graph (jobs/execution/graph.py) -------------------------------------

def _run_staged(spec: SweepSpec, store, settings_):
    """Every stage in graph order (as the Dask workers would), then the sweep job."""
    from jobs.execution.graph import sweep_stages
    from jobs.sweeps.sweep import run_stage

    stage_work: dict[str, int] = {}
    for stage in sweep_stages(spec):
        for name, count in run_stage(spec, stage.task, store, settings_).items():
            stage_work[name] = stage_work.get(name, 0) + count
    return run_sweep(spec, store, settings_, stage_work=stage_work)


def test_a_sweep_run_as_stages_gives_the_same_points(sweep_env, tmp_path):
    _, _, direct = sweep_env
    settings_ = Settings(data_dir=tmp_path / "data")
    store = open_store(settings_)
    staged = _run_staged(small_spec(), store, settings_)
    store.close()
    # The stages made the reference, every cache and every NIRC/NRC point; the sweep
    # job only added the equal-time series.
    assert staged.work["reference_rendered"] == 0 and staged.work["snapshots_trained"] == 0
    assert staged.work["snapshots_reused"] == 4 and staged.work["points_reused"] == 6
    assert staged.stage_work["reference_rendered"] == 1
    assert staged.stage_work["snapshots_trained"] == 4
    assert staged.stage_work["points_rendered"] == 6
    assert len(staged.snapshots) == 4     # every cache's training curve is in the plot
    for name in ("NIRC", "NRC"):
        for a, b in zip(_series(direct, name), _series(staged, name), strict=True):
            assert (a.eps, a.mask_pct) == (b.eps, b.mask_pct)
            assert b.mrse == pytest.approx(a.mrse, rel=1e-4), name


def test_an_nc_sweep_run_as_stages_renders_its_points_in_the_stages(sweep_env):
    settings_, store, _ = sweep_env
    spec = small_spec(eps=None, nc=[1, 2], seeds=2)
    result = _run_staged(spec, store, settings_)
    assert result.work["points_rendered"] == 0 and result.work["points_reused"] == 2
    assert result.stage_work["points_rendered"] == 2
    assert [row.nc for row in result.rows] == [row.value for row in result.rows] == [1, 2]
    assert result.kind == "parameter" and result.parameter == "nc"


# ---- A parameter sweep (any declared parameter of any method) -----------------------

def _parameter_spec(**overrides) -> SweepSpec:
    """A toy parameter: pt's Russian-roulette survival, which lengthens paths as it grows."""
    values = dict(scene="cornell-box", resolution=16, seeds=2, methods=["pt"],
                  parameter=ParameterSweep(name="rr_survival", values=[0.5, 0.95]),
                  params={"rr_depth": 1}, reference=ReferenceSpec(spp=256))
    return SweepSpec(**{**values, **overrides})


@pytest.fixture(scope="module")
def parameter_env(tmp_path_factory, mi):
    settings_ = Settings(data_dir=Path(tmp_path_factory.mktemp("parameter")) / "data")
    store = open_store(settings_)
    yield settings_, store, run_sweep(_parameter_spec(), store, settings_)
    store.close()


def test_a_parameter_sweep_renders_a_row_per_value_with_the_same_seeds(parameter_env):
    _, store, result = parameter_env
    assert result.kind == "parameter" and result.parameter == "rr_survival"
    assert [(row.series, row.value) for row in result.rows] == [("pt", 0.5), ("pt", 0.95)]
    runs = [store.get_run(row.id) for row in result.rows]
    assert [run.params["rr_survival"] for run in runs] == [0.5, 0.95]
    assert {run.params["rr_depth"] for run in runs} == {1} and {run.seeds for run in runs} == {2}
    assert runs[0].reference_id == runs[1].reference_id
    for row in result.rows:
        assert row.finite and row.mrse is not None and np.isfinite(row.mrse)
    # The swept value reached the renderer: higher survival, longer paths.
    assert result.rows[1].avg_path_length > result.rows[0].avg_path_length
    assert Path(result.files["parameter"]).stat().st_size > 0
    assert result.work["points_rendered"] == 2 and result.work["reference_rendered"] == 1


def test_a_repeated_or_staged_parameter_sweep_renders_nothing_new(parameter_env):
    settings_, store, first = parameter_env
    again = run_sweep(_parameter_spec(), store, settings_)
    assert again.work["points_rendered"] == 0 and again.work["points_reused"] == 2
    assert [row.id for row in again.rows] == [row.id for row in first.rows]
    staged = _run_staged(_parameter_spec(parameter=ParameterSweep(
        name="rr_survival", values=[0.5, 0.95, 0.8])), store, settings_)
    assert staged.stage_work["points_rendered"] == 1 and staged.stage_work["points_reused"] == 2
    assert [row.value for row in staged.rows] == [0.5, 0.95, 0.8]


@pytest.mark.parametrize("values, fragment", [
    ({"parameter": ParameterSweep(name="unknown", values=[1])}, "pt has no parameter"),
    ({"parameter": ParameterSweep(name="rr_survival", values=[2.0])}, "less than or equal"),
    ({"params": {"rr_survival": 0.5}}, "is swept"),
    ({"eps": [0.1]}, "neither eps nor nc"),
    ({"methods": ["pt", "nirc"], "parameter": ParameterSweep(name="nc", values=[1])},
     "pt has no parameter"),
])
def test_bad_parameter_sweeps_are_explained(values, fragment):
    with pytest.raises(ValueError, match=fragment):
        _parameter_spec(**values)


def test_the_nc_sweep_takes_a_termination_the_method_accepts():
    """An N_c sweep's top-level termination (the form of old clients and stored specs)
    is NIRC's parameter; elsewhere only the default, which every other sweep stores."""
    spec = small_spec(eps=None, termination="sph")
    assert spec.is_nc_sweep and spec.params["termination"] == "sph"
    assert spec == small_spec(eps=None, params={**SMALL, "termination": "sph"})
    default = small_spec().model_dump(mode="json")["termination"]
    assert small_spec(termination=default) == small_spec()
    assert small_spec(eps=None, termination=default) == small_spec(eps=None)
    for values, fragment in [({"eps": None, "termination": "magic"}, "termination"),
                             ({"termination": "sph"}, "is the N_c sweep's"),
                             ({"eps": None, "termination": "sph",
                               "params": {"termination": "adaptive"}}, "given twice"),
                             ({"eps": None, "params": {"estimator": "unbiased"}},
                              "needs biased nirc")]:
        with pytest.raises(ValueError, match=fragment):
            small_spec(**values)


# ---- A parameter inside a mapping parameter (a dotted path) --------------------------

def _policy_spec(**overrides) -> SweepSpec:
    """grid-cache's var-bound threshold, a field of its termination_params."""
    values = dict(scene="cornell-box", resolution=8, seeds=2, methods=["grid-cache"],
                  parameter=ParameterSweep(name="termination_params.threshold",
                                           values=[0.0, 10.0]),
                  params={"termination": "var-bound", "prefill_frames": 4,
                          "termination_params": {"relative": False}},
                  reference=ReferenceSpec(spp=64))
    return SweepSpec(**{**values, **overrides})


def test_a_dotted_parameter_sets_one_field_of_a_mapping_parameter():
    spec = _policy_spec()
    params = spec.parameter_point("grid-cache", 0.5)
    assert params.termination_params == policy_params("var-bound", relative=False,
                                                      threshold=0.5)
    assert params.termination == "var-bound" and params.prefill_frames == 4
    with pytest.raises(ValueError, match="threshold"):
        _policy_spec(parameter=ParameterSweep(name="termination_params.threshold",
                                              values=[-1.0]))
    with pytest.raises(ValueError, match="has no parameter 'nowhere'"):
        _policy_spec(parameter=ParameterSweep(name="nowhere.threshold", values=[1.0]))
    with pytest.raises(ValueError, match="is swept"):
        _policy_spec(params={"termination_params": {"threshold": 1.0}})


def test_a_policy_parameter_sweep_renders_its_rows(tmp_path, mi):
    """The generic sweep runs grid-cache's var-bound over its threshold, nothing
    policy-specific in jobs/: t = 0 ends every path at its first hit, t = 10 hardly any."""
    settings_ = Settings(data_dir=tmp_path / "data")
    store = open_store(settings_)
    try:
        result = run_sweep(_policy_spec(), store, settings_)
    finally:
        store.close()
    assert [(row.series, row.value) for row in result.rows] == [("grid-cache", 0.0),
                                                                  ("grid-cache", 10.0)]
    assert all(row.finite for row in result.rows)
    assert result.rows[0].avg_path_length < result.rows[1].avg_path_length


# ---- What a point renders, and where a sweep comes from ----------------------------

def test_render_keys_tell_points_apart_by_parameters_masks_and_caches(sweep_env):
    """Rows of the sweep table merge only on equal render keys (service/tables.py).
    Planted: saturated masks alike (every pixel) with N_c 1 and 2 at v1 (the equal-time
    series' calibrated points), which the table's old rule merged, key apart."""
    from jobs.sweeps.sweep import _Sweep

    settings_, store, result = sweep_env
    sweep = _Sweep(small_spec(), store, settings_, None, whole=False)
    full = [np.ones((16, 16), dtype=bool)] * 2
    one, two = sweep.params("nirc"), sweep.params("nirc", 2)
    key = sweep.render_key("nirc", one, full)
    assert key == sweep.render_key("nirc", one, [m.copy() for m in full])
    assert key != sweep.render_key("nirc", two, full)
    assert key != sweep.render_key("nrc", sweep.params("nrc"), full)
    half = [full[0], np.tri(16, dtype=bool)]
    assert key != sweep.render_key("nirc", one, half)
    # Every rendered point stores its key, and the stored rows carry it.
    assert all(row.render_key for row in result.rows)


def test_an_equal_time_series_without_its_budget_method_is_listed_as_skipped():
    from jobs.sweeps.sweep import unpaired_equal_time

    skipped = unpaired_equal_time(["nirc"])
    assert [s.method for s in skipped] == ["nirc-equal-time"]
    assert "add nrc to the sweep's methods" in skipped[0].reason
    assert unpaired_equal_time(["nirc", "nrc"]) == [] and unpaired_equal_time(["nrc"]) == []


ROOM_XML = """<scene version="3.0.0">
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <shape type="rectangle"><bsdf type="diffuse"/></shape>
  <emitter type="constant"/>
</scene>
"""


def test_a_sweep_of_a_scene_file_reuses_its_points_under_the_service_s_name(tmp_path, mi):
    """The CLI names a scene file by its path, the service by its stored copy's id: the
    points are keyed by the scene's content, so the second sweep renders nothing (it
    rendered both points again when keyed by the name)."""
    from jobs.protocol.scene_store import rest_scene

    (tmp_path / "scenes").mkdir()
    path = tmp_path / "scenes" / "room.xml"
    path.write_text(ROOM_XML)
    settings_ = Settings(data_dir=tmp_path / "data", scene_roots=[tmp_path / "scenes"])
    store = open_store(settings_)
    try:
        spec = _parameter_spec(scene=str(path), resolution=8, reference=ReferenceSpec(spp=16))
        first = run_sweep(spec, store, settings_)
        stored_name = rest_scene(str(path), settings_)
        assert stored_name != str(path)
        again = run_sweep(spec.model_copy(update={"scene": stored_name}), store, settings_)
    finally:
        store.close()
    assert first.work["points_rendered"] == 2
    assert again.work["points_rendered"] == 0 and again.work["points_reused"] == 2
    assert [row.id for row in again.rows] == [row.id for row in first.rows]


# ---- Equal-time probes on a loaded machine -----------------------------------------

def _probing_sweep(monkeypatch, loaded_tries: int, allow_loaded: bool):
    """A sweep object with only what its equal-time probe reads, whose first
    ``loaded_tries`` probes are timed on a loaded machine at 10x the quiet 2 ms; returns
    it and the warm-up flag of every probe taken."""
    from types import SimpleNamespace

    from jobs.sweeps import sweep as sweep_module

    warmups: list[bool] = []

    def frames(stage, *, hooks, **_):
        warmups.append(hooks.warmup)
        loaded = len(warmups) <= loaded_tries
        return SimpleNamespace(timings={
            "frame_median_s": 0.02 if loaded else 0.002,
            "load": {"loaded": loaded, "reasons": ["tasks waited for a core 60 %"] * loaded}})

    monkeypatch.setattr(sweep_module, "run_frames", frames)
    monkeypatch.setattr(sweep_module, "render_stage", lambda *args: None)
    monkeypatch.setattr(sweep_module, "v1_mask", lambda bias, eps: None)
    integrator = SimpleNamespace(set_v1_mask=lambda mask: None)
    runner = SimpleNamespace(
        spec=small_spec(allow_loaded=allow_loaded), _probes={}, work={"calibrations": 0},
        prepared=SimpleNamespace(scene=None), snapshot=lambda method, seed: None,
        bias=lambda snap: None, frozen_integrator=lambda *args: integrator,
        params=lambda method, nc=None: {},
        report=lambda *args: None)
    return runner, warmups


@pytest.mark.parametrize("allow_loaded", [False, True])
def test_an_equal_time_probe_on_a_loaded_machine_is_left_out_unless_allowed(
        monkeypatch, allow_loaded):
    """The first probe runs loaded at 20 ms: left out and taken again (compiled once),
    the quiet 2 ms counts; allowed (--allow-loaded), the loaded 20 ms counts, as every
    probe did before."""
    from jobs.protocol.calibration import LoadLog
    from jobs.sweeps.sweep import _Sweep

    runner, warmups = _probing_sweep(monkeypatch, 1, allow_loaded)
    log = LoadLog(runner.spec.allow_loaded)
    seconds = _Sweep.probe(runner, "nirc", 0.3, log, nc=2)
    if allow_loaded:
        assert (seconds, log.left_out, warmups) == (0.02, [], [True])
        assert log.merged()["loaded"]
    else:
        assert (seconds, warmups) == (0.002, [True, False])
        assert log.left_out == ["NIRC N_c 2 at eps 0.3: 20 ms left out, machine loaded "
                                "(tasks waited for a core 60 %)"]
        assert not log.merged()["loaded"]


def test_a_sweep_whose_every_probe_is_loaded_stops_with_a_message(monkeypatch):
    from jobs.protocol.calibration import LOADED_RETRIES, LoadedMachineError, LoadLog
    from jobs.sweeps.sweep import _Sweep
    from service.errors import is_user_error

    runner, warmups = _probing_sweep(monkeypatch, LOADED_RETRIES + 1, False)
    with pytest.raises(LoadedMachineError, match="--allow-loaded") as caught:
        _Sweep.probe(runner, "nrc", 0.3, LoadLog(runner.spec.allow_loaded))
    assert len(warmups) == LOADED_RETRIES + 1 and is_user_error(caught.value)


def test_allowing_loaded_probes_keys_another_sweep_and_the_default_keeps_its_key():
    from jobs.protocol.spec import keyed_budget
    from renderers.seeding import digest

    quiet, loaded = small_spec(allow_loaded=False), small_spec(allow_loaded=True)
    before = quiet.model_dump(mode="json")
    del before["allow_loaded"]                                # the spec before the flag
    assert quiet.key("d") == digest("sweep-spec", before, "d", quiet.versions())
    assert loaded.key("d") != quiet.key("d")
    assert "allow_loaded" in keyed_budget(loaded.model_dump(mode="json"))
