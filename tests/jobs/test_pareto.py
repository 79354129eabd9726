"""The pareto command's plan (read from the method registry), its evaluation of measured
points (fronts, speed-ups) and its plot, without rendering; and, rendering a tiny scene,
that a repeated call reuses its stored runs."""

from __future__ import annotations

from datetime import UTC, datetime
from types import SimpleNamespace

import numpy as np
import pytest

import jobs.pareto.pareto as pareto_module
from jobs.pareto.pareto import (
    PARETO_METRICS,
    ParetoPoint,
    Timing,
    _evaluate,
    baseline_flags,
    baselines,
    point_key,
    run_pareto,
    without_stage_points,
)
from jobs.pareto.plan import (
    PAPER_PT,
    STRONGEST_PT,
    ParetoSpec,
    interleave,
    plan,
    pt_core_methods,
    run_spec,
)
from jobs.protocol.results import RunResult
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.views.plots import plot_pareto
from renderers.methods import BASELINE, METHODS


def _series_by_name(spec: ParetoSpec) -> dict[str, list]:
    series, _ = plan(spec)
    return {points[0].series: points for points in series}


def test_the_plan_reads_knobs_and_comparison_runs_from_the_registry():
    series, skipped = plan(ParetoSpec(scene="cornell-box"))
    planned = {p.method for points in series for p in points}
    for name, method in METHODS.items():
        if name == BASELINE:
            continue
        knob_series = [s for s in series if s[0].method == name and len(s) > 1
                       and not s[0].named]
        misfit = [entry for entry in skipped if entry["method"] == name
                  and entry["reason"].startswith("not comparable")]
        if method.knob is not None and not misfit:
            # an spp knob runs on PT's spp grid, another knob over its candidates
            grid = [1, 2, 4, 8, 16] if method.knob.name == "spp" else method.knob.candidates
            assert len(knob_series) == 1 and len(knob_series[0]) == len(grid)
        if method.knob is None and not method.comparison:
            assert name not in planned
            assert {"method": name, "reason": "declares neither an equal-time knob nor "
                                              "comparison runs"} in skipped
    by_name = _series_by_name(ParetoSpec(scene="cornell-box", knob_values={"nirc": [1, 4]}))
    # biased NIRC over N_c; its unbiased comparison run is off that curve: a point of its own.
    assert [p.params["nc"] for p in by_name["NIRC"]] == [[1], [4]]
    assert by_name["NIRC unbiased"][0].params["estimator"] == "unbiased"
    assert len(by_name["NRC"]) == 1 and by_name["NRC"][0].params["pretrain_frames"] == 16
    assert "pretrain_frames" not in by_name["paper's PT"][0].params


def test_the_plan_has_the_papers_pt_and_the_strongest_pts_candidates():
    """The paper's PT is pt's defaults (fixed roulette), labelled; the strongest PT's
    candidates are the PT core's methods with throughput roulette, over the same spp."""
    series, _ = plan(ParetoSpec(scene="cornell-box", pt_spp=[1, 4], methods=["pt", "nirc"]))
    paper = [s for s in series if s[0].named == PAPER_PT]
    assert len(paper) == 1 and paper[0][0].series == "paper's PT"
    assert [(p.method, p.spp, p.label) for p in paper[0]] == [
        (BASELINE, 1, "paper's PT spp=1"), (BASELINE, 4, "paper's PT spp=4")]
    assert METHODS[BASELINE].params(**paper[0][0].params).rr_mode == "fixed"
    candidates = [s for s in series if s[0].named == STRONGEST_PT]
    assert sorted(s[0].method for s in candidates) == sorted(pt_core_methods()) \
        == ["pt", "pt-power", "pt-spatial"]
    for points in candidates:
        assert [p.spp for p in points] == [1, 4]
        assert all(p.params["rr_mode"] == "throughput" for p in points)
    assert {s[0].named for s in series if s[0].method not in pt_core_methods()} == {""}


@pytest.mark.parametrize("baseline", [PAPER_PT, STRONGEST_PT, "paper's PT", "NIRC"])
def test_a_baseline_is_a_named_pt_or_a_series_of_two_points_or_more(baseline):
    plan(ParetoSpec(scene="cornell-box", methods=["pt", "nirc"], baseline=baseline))


def test_a_method_that_cannot_render_at_the_shared_depth_is_skipped_saying_why():
    # restir-di renders direct light only (max_depth 2); the default depth is unbounded.
    series, skipped = plan(ParetoSpec(scene="many-lights"))
    assert "restir-di" not in {p.method for points in series for p in points}
    reason = next(e["reason"] for e in skipped if e["method"] == "restir-di")
    assert reason.startswith("not comparable at these settings") and "max_depth" in reason
    # at its depth it is planned on PT's spp grid, like the other spp-knob methods
    by_name = _series_by_name(ParetoSpec(scene="many-lights", max_depth=2, pt_spp=[1, 4]))
    assert [p.spp for p in by_name["ReSTIR DI"]] == [1, 4]
    assert [p.spp for p in by_name["NVC lights"]] == [1, 4]
    # named explicitly, the mismatch is an error that says what is wrong
    with pytest.raises(ValueError, match="max_depth"):
        plan(ParetoSpec(scene="many-lights", methods=["pt", "restir-di"]))


def test_points_are_run_round_robin_over_the_series():
    series, _ = plan(ParetoSpec(scene="cornell-box", pt_spp=[4, 1, 2, 2],
                                methods=["pt", "nirc", "pt"],
                                knob_values={"nirc": [1, 2]}))
    pts = ["paper's PT", "PT (throughput RR)", "pt-power (throughput RR)",
           "pt-spatial (throughput RR)"]
    assert [p.label for p in interleave(series)] == [
        *(f"{s} spp=1" for s in pts), "NIRC nc=1", "NIRC unbiased",
        *(f"{s} spp=2" for s in pts), "NIRC nc=2", *(f"{s} spp=4" for s in pts)]


@pytest.mark.parametrize("changes, fragment", [
    ({"methods": ["nirc"]}, "baseline"),
    ({"pt_spp": [4, 4]}, "at least two"),
    ({"knob_values": {"nrc": [1, 2]}}, "no equal-time knob"),
    ({"knob_values": {"pt": [1, 2]}}, "--pt-spp"),
    ({"methods": ["pt", "no-such"]}, "unknown method"),
    ({"knob_values": {"nirc": [300]}}, "nc"),
    ({"pt_spp": [1, 1 << 17]}, "spp"),
    ({"baseline": "no-such"}, "unknown baseline 'no-such': give paper-pt, strongest-pt"),
    ({"baseline": "NRC"}, "single point"),
    ({"without_stages": ["render"]}, "other than render"),
    ({"without_stages": ["prop agation"]}, "--without-stage"),
])
def test_bad_plans_are_errors_before_anything_renders(changes, fragment):
    with pytest.raises(ValueError, match=fragment):
        plan(ParetoSpec(scene="cornell-box", **changes))


def _point(series: str, seconds: float, mrse: float | None, flip: float,
           named: str = "") -> ParetoPoint:
    """A measured point (its run's fields are placeholders: only the pareto columns count)."""
    run = {"id": 1, "created_at": datetime(2026, 1, 1, tzinfo=UTC), "scene": "cornell-box",
           "scene_fingerprint": "-", "method": "pt", "params": {}, "resolution": [8, 8],
           "spp": 1, "frames": 1, "seeds": 2, "device_key": "-", "quality": {},
           "estimator_version": 1, "metric_version": 1, "current": True}
    return ParetoPoint(
        **run, series=series, label=f"{series} {seconds}", baseline=False,
        named_baseline=named, reused=False,
        seconds_per_frame=seconds, seconds_spread=[0.9 * seconds, 1.1 * seconds],
        timing_samples=[seconds, 0.95 * seconds, 1.05 * seconds], run_seconds_per_frame=seconds,
        mrse=mrse, mrse_per_seed=[mrse, mrse] if mrse is not None else [None, None],
        flip=flip, flip_per_seed=[0.98 * flip, 1.02 * flip])


def test_fronts_and_speed_ups_of_measured_points():
    points = [_point("PT", 0.01 * n, 0.4 / n, 0.3 / n ** 0.5, named=PAPER_PT)
              for n in (1, 2, 4, 8)]
    points += [_point("NIRC", 0.02, 0.05, 0.2),       # PT reaches MRSE 0.05 at 0.08 s: 4x
               _point("NIRC", 0.5, 0.02, 0.01),       # below PT's range: '>'
               _point("NRC", 0.05, None, 0.5)]        # MRSE withheld: n/a
    _evaluate(points, 200, PAPER_PT)
    # NIRC at 0.02 s beats PT at 2, 4 and 8 spp (as fast or faster, less error).
    assert [p.front_mrse for p in points] == [True, False, False, False, True, True, False]
    assert points[4].speedup_mrse.relation == "="
    assert points[4].speedup_mrse.value == pytest.approx(4.0)
    lo, hi = points[4].speedup_mrse.ci95
    assert lo <= 4.0 <= hi
    assert points[5].speedup_mrse.relation == ">"
    assert points[5].speedup_mrse.value == pytest.approx(0.08 / 0.5)
    assert points[6].speedup_mrse.relation == "n/a" and "MRSE" in points[6].speedup_mrse.note
    assert points[6].speedup_flip.relation == "<"
    assert all(p.speedup_mrse is None and p.baseline for p in points[:4])
    assert points[4].speedup_mrse.against == "paper's PT"
    # The JSON shape is the model's: a dump validates back to the same point.
    assert [ParetoPoint.model_validate(p.model_dump(mode="json")) for p in points] == points


def _pt_series() -> list[ParetoPoint]:
    """Planted PT series at 0.01 * n s: candidate 'flat' (MRSE 0.4 / n^0.8), candidate
    'steep' (better only from 0.04 s on: 0.4 * (n / 4)^-1.5 / 4^0.8), and the paper's PT,
    flat's errors at twice its times."""
    flat = [_point("flat", 0.01 * n, 0.4 * n ** -0.8, 0.3, named=STRONGEST_PT)
            for n in (1, 2, 4, 8, 16)]
    steep = [_point("steep", 0.01 * n, 0.4 * 4 ** -0.8 * (n / 4) ** -1.5, 0.3,
                    named=STRONGEST_PT) for n in (1, 2, 4, 8, 16)]
    paper = [_point("paper's PT", 0.02 * n, 0.4 * n ** -0.8, 0.3, named=PAPER_PT)
             for n in (1, 2, 4, 8, 16)]
    return flat + steep + paper


def test_speed_ups_are_against_the_strongest_pt_unless_another_baseline_is_named():
    early = _point("cache", 0.01, 0.4 * 2 ** -0.8, 0.3)          # flat reaches it at 0.02 s
    late = _point("cache", 0.03, 0.4 * 4 ** -0.8 * 3 ** -1.5, 0.3)   # steep at 0.12 s
    points = [*_pt_series(), early, late]
    _evaluate(points, 100, ParetoSpec(scene="cornell-box").baseline)   # the default
    assert {p.series for p in points if p.baseline} == {"flat", "steep"}
    assert (early.speedup_mrse.via, early.speedup_mrse.relation) == ("flat", "=")
    assert early.speedup_mrse.value == pytest.approx(2.0)
    assert (late.speedup_mrse.via, late.speedup_mrse.relation) == ("steep", "=")
    assert late.speedup_mrse.value == pytest.approx(4.0)
    assert late.speedup_mrse.against == "strongest PT"
    # The paper's PT is a series of its own, measured against the strongest PT: its
    # 1-spp point (flat's error at twice flat's time) is half as fast.
    paper_1 = next(p for p in points if p.series == "paper's PT")
    assert not paper_1.baseline and paper_1.speedup_mrse.value == pytest.approx(0.5)

    points = [*_pt_series(), early, late]
    _evaluate(points, 100, PAPER_PT)
    assert {p.series for p in points if p.baseline} == {"paper's PT"}
    assert early.speedup_mrse.value == pytest.approx(4.0)
    assert late.speedup_mrse.relation == ">" and late.speedup_mrse.against == "paper's PT"
    # A series named by its label: flat alone does not reach late's error in its range.
    points = [*_pt_series(), early, late]
    _evaluate(points, 100, "flat")
    assert late.speedup_mrse.relation == ">" and late.speedup_mrse.against == "flat"
    assert next(p for p in points if p.series == "steep").speedup_mrse is not None
    with pytest.raises(ValueError, match="unknown baseline 'bogus'"):
        _evaluate([*_pt_series(), early], 100, "bogus")


def test_the_result_carries_the_strongest_pts_envelope_and_definition():
    points = _pt_series()
    _evaluate(points, 100, STRONGEST_PT)
    found = baselines(points, STRONGEST_PT)
    assert found["speedups_against"] == "strongest PT"
    strongest = found[STRONGEST_PT]
    assert strongest["candidates"] == ["flat", "steep"]
    assert "lower error envelope at equal time" in strongest["definition"]
    # steep is lower than flat from 0.04 s on (they meet there) and nowhere before
    assert [(p["series"], p["from_s"], p["to_s"]) for p in strongest["envelope"]["mrse"]] == [
        ("flat", pytest.approx(0.01), pytest.approx(0.04)),
        ("steep", pytest.approx(0.04), pytest.approx(0.16))]
    assert found[PAPER_PT]["label"] == "paper's PT"


def test_the_plots_draw_the_envelope_of_the_json_and_leave_loaded_points_out(
        tmp_path, monkeypatch):
    """pareto_<error>.png draws the strongest PT over the span of the JSON's envelope
    pieces; steep's last point, timed on a loaded machine, is no vertex of it unless
    loaded timings are allowed (flat is the envelope there instead)."""
    from jobs.pareto.pareto import ParetoResult, write_outputs

    drawn = {}
    monkeypatch.setattr(pareto_module, "plot_pareto", lambda points, key, *args, envelope:
                        drawn.__setitem__(key, envelope))
    last = {}
    for allow_loaded in (False, True):
        points = _pt_series()
        points[9].loaded = True                 # steep at 0.16 s
        spec = ParetoSpec(scene="cornell-box", allow_loaded=allow_loaded)
        result = ParetoResult(spec=spec, device="cpu", reference_id=1, points=points,
                              skipped=[], timing={}, bootstrap={}, left_out=[],
                              baselines=baselines(points, STRONGEST_PT, allow_loaded),
                              work={})
        write_outputs(result, tmp_path)
        pieces = result.baselines[STRONGEST_PT]["envelope"]["mrse"]
        (line,) = drawn["mrse"]
        assert len(drawn) == len(PARETO_METRICS)
        assert line[0][0] == pytest.approx(pieces[0]["from_s"]) == 0.01
        assert line[-1][0] == pytest.approx(pieces[-1]["to_s"]) == 0.16
        last[allow_loaded] = (pieces[-1]["series"], line[-1][1])
    assert last[False] == ("flat", pytest.approx(points[4].mrse))
    assert last[True] == ("steep", pytest.approx(points[9].mrse))


def test_a_stage_taken_out_of_a_points_time_is_a_series_beside_it_off_the_fronts():
    """grid-cache with and without its propagation pass: the derived point's samples are
    each sample less its frame's stage; it gets a speed-up but never a front place (were
    it on the front, it would push its own measured point off: same error, less time)."""
    timing = Timing([0.10, 0.12, 0.11], parts=[
        {"propagation": 0.09, "render": 0.01}, {"propagation": 0.10, "render": 0.02},
        {"propagation": 0.095, "render": 0.015}])
    assert timing.without("propagation") == pytest.approx([0.01, 0.02, 0.015])
    assert timing.without("training") is None          # a stage its frames did not run
    assert Timing([0.1, 0.2], parts=[{"propagation": 0.05}]).without("propagation") is None

    pt = [_point("PT", 0.01 * n, 0.4 / n, 0.3 / n ** 0.5, named=PAPER_PT) for n in (1, 2, 4, 8)]
    grid = _point("grid", 0.11, 0.02, 0.05)
    plain = Timing([0.01, 0.01, 0.01])
    derived = without_stage_points([*pt, grid], [plain] * 4 + [timing], "propagation")
    assert [p.series for p in derived] == ["grid without propagation"]
    (lean,) = derived
    assert lean.without_stages == ["propagation"] and lean.seconds_per_frame == 0.015
    assert lean.timing_samples == pytest.approx([0.01, 0.02, 0.015])
    assert lean.mrse_per_seed == grid.mrse_per_seed
    points = [*pt, grid, lean]
    _evaluate(points, 200, PAPER_PT)
    assert grid.front_mrse and not lean.front_mrse and not lean.front_flip
    assert lean.speedup_mrse.relation == ">"            # below PT's curve: PT needs > 0.08 s
    assert lean.speedup_mrse.value == pytest.approx(0.08 / 0.015)
    assert ParetoPoint.model_validate(lean.model_dump(mode="json")) == lean


def test_a_grid_cache_probe_gives_its_time_without_the_propagation_pass(mi):
    """What --without-stage reads of a real probe: the breakdown of its median frame."""
    from jobs.protocol.calibration import probe_timings
    from renderers.methods import parse_params
    from renderers.scenes import load_scene

    probe = probe_timings(load_scene("cornell-box", 8), "grid-cache",
                          parse_params("grid-cache", {"prefill_frames": 1}), 1, 2)
    parts = probe["breakdown"]["parts_s"]
    (lean,) = Timing([probe["frame_median_s"]], parts=[parts]).without("propagation")
    assert 0 < lean < probe["frame_median_s"]
    assert lean == pytest.approx(probe["frame_median_s"] - parts["propagation"])


def test_a_baseline_whose_time_does_not_grow_with_spp_is_flagged():
    def pt(spp: int, seconds: float, series: str = "PT") -> ParetoPoint:
        return _point(series, seconds, 0.1, 0.1, named=STRONGEST_PT).model_copy(
            update={"spp": spp})

    assert baseline_flags([pt(1, 0.01), pt(2, 0.02), pt(4, 0.04)]) == []
    flags = baseline_flags([pt(1, 0.01), pt(4, 0.018), pt(2, 0.02), pt(1, 0.01, "B"),
                            pt(2, 0.02, "B")])
    assert len(flags) == 1 and "PT is not monotone in spp: 2 spp 20 ms/frame >= 4 spp " \
                               "18 ms/frame" in flags[0]


def test_timing_samples_that_spread_or_ran_loaded_are_flagged():
    assert Timing([1.0, 1.05, 0.98]).flags() == []
    assert "spread 20 %" in Timing([1.0, 1.2, 1.0]).flags()[0]
    # A run's own frames are not interleaved probes: their spread is not judged.
    assert Timing([1.0, 1.2, 1.0], interleaved=False).flags() == []
    loaded = {"loaded": True, "reasons": ["other work held the CPU"]}
    assert "loaded" in Timing([1.0, 1.0], [None, loaded]).flags()[0]


def test_points_timed_on_a_loaded_machine_are_left_out_unless_allowed():
    """A loaded point's time says how busy the machine was: a spuriously fast cache point
    would top the front, a slow PT point would bend the baseline's curve. Left out (and
    listed) by default; with allow_loaded both count again, which the asserts on the
    planted points tell apart."""
    def evaluated(allow_loaded: bool) -> tuple[list[ParetoPoint], list[dict[str, str]]]:
        points = [_point("PT", 0.01 * n, 0.4 / n, 0.3 / n ** 0.5, named=PAPER_PT)
                  for n in (1, 2, 4, 8)]
        slow_pt = _point("PT", 0.4, 0.025, 0.075, named=PAPER_PT)   # 16 spp, loaded
        quiet = _point("NIRC", 0.02, 0.03, 0.2)        # below the quiet PT's errors
        fast = _point("NRC", 0.005, 0.05, 0.2)         # loaded: faster than PT at 1 spp
        for point in (slow_pt, fast):
            point.loaded = True
        points += [slow_pt, quiet, fast]
        return points, _evaluate(points, 100, PAPER_PT, allow_loaded)

    points, left_out = evaluated(False)
    slow_pt, quiet, fast = points[4:]
    assert [item["label"] for item in left_out] == [slow_pt.label, fast.label]
    assert all("loaded machine" in item["reason"] for item in left_out)
    assert not fast.front_mrse and not slow_pt.front_mrse and quiet.front_mrse
    assert points[0].front_mrse                               # PT at 1 spp: fastest quiet
    assert fast.speedup_mrse.relation == "n/a" and "loaded" in fast.speedup_mrse.note
    # The quiet PT's curve ends at MRSE 0.05 (0.08 s): a bound, not interpolated.
    assert quiet.speedup_mrse.relation == ">"
    assert quiet.speedup_mrse.value == pytest.approx(0.08 / 0.02)
    # Allowed: the loaded points count, moving the front and the baseline's curve.
    points, left_out = evaluated(True)
    slow_pt, quiet, fast = points[4:]
    assert left_out == [] and fast.front_mrse and slow_pt.front_mrse
    assert not points[0].front_mrse and fast.speedup_mrse.relation != "n/a"
    assert quiet.speedup_mrse.relation == "="


def test_the_table_marks_loaded_times_and_shows_the_runs_own_time():
    """The point's time (interleaved rounds) and the run's own stored time are two
    columns; the run's is the one every other view shows (RunResult.seconds_per_frame)."""
    from rich.console import Console

    from jobs.pareto.pareto import ParetoResult
    from service.pareto_table import pareto_table

    points = [_point("PT", 0.01 * n, 0.4 / n, 0.3, named=PAPER_PT) for n in (1, 2, 4)]
    points[1].loaded = True
    points[2] = points[2].model_copy(update={"run_seconds_per_frame": 0.0475,
                                             "timing_flags": ["loaded: busy"]})
    spec = ParetoSpec(scene="cornell-box")
    left_out = _evaluate(points, 100, PAPER_PT)
    result = ParetoResult(spec=spec, device="cpu", reference_id=1, points=points, skipped=[],
                          timing={}, bootstrap={"resamples": 100}, left_out=left_out,
                          baselines=baselines(points, PAPER_PT),
                          work={"points_reused": 0, "points_rendered": 3})
    console = Console(width=400, record=True)
    console.print(pareto_table(result))
    text = console.export_text()
    rows = {line.split("│")[2].strip(): [c.strip() for c in line.split("│")]
            for line in text.splitlines() if line.count("│") > 5}
    assert rows["PT 0.02"][4] == "20L" and rows["PT 0.01"][4] == "10"
    assert rows["PT 0.04"][4] == "40" and rows["PT 0.04"][6] == "47.5L"
    assert f"left out: PT 0.02: {left_out[0]['reason']}" in text


def test_the_plot_draws_every_metric(tmp_path):
    points = [_point("PT", 0.01 * n, 0.4 / n, 0.3, named=PAPER_PT) for n in (1, 2)]
    points.append(_point("NIRC", 0.02, 0.05, 0.2))
    points[1].loaded = True               # drawn crossed
    _evaluate(points, 100, PAPER_PT, allow_loaded=True)
    for metric in PARETO_METRICS:
        path = plot_pareto([p.model_dump() for p in points], metric.field, metric.label, tmp_path / f"{metric.field}.png",
                           "test")
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


TINY = ParetoSpec(scene="cornell-box", resolution=8, frames=1, seeds=2, pt_spp=[1, 2],
                  methods=["pt"], ref_spp=64, timing_rounds=1, probe_frames=1,
                  resamples=100)
#: The PT series every call renders: the paper's PT and the strongest PT's candidates.
PT_RUNS = ["pt", "pt", "pt-power", "pt-spatial"]


def test_a_repeated_call_reuses_its_stored_runs_and_measures_time_again(mi, data_dir,
                                                                        monkeypatch):
    renders = []
    execute = pareto_module.execute
    monkeypatch.setattr(pareto_module, "execute",
                        lambda job, *args, **kwargs: renders.append(job.method + str(job.spec.spp))
                        or execute(job, *args, **kwargs))
    settings = Settings()
    store = open_store(settings)
    first = run_pareto(TINY, store, settings)
    assert sorted(renders) == sorted(f"{m}{spp}" for m in PT_RUNS for spp in (1, 2))
    assert not any(p.reused for p in first.points)
    assert first.work["points_rendered"] == 8 and first.work["points_reused"] == 0

    renders.clear()
    second = run_pareto(TINY, store, settings)
    assert renders == []                                    # nothing rendered again
    assert all(p.reused for p in second.points) and second.work["points_reused"] == 8
    assert [p.id for p in second.points] == [p.id for p in first.points]
    for before, after in zip(first.points, second.points, strict=True):
        for metric in PARETO_METRICS:
            key = metric.field
            assert getattr(after, key) == getattr(before, key) is not None
            assert getattr(after, f"{key}_per_seed") == getattr(before, f"{key}_per_seed")
        assert len(after.timing_samples) == 1               # timed again, in one round

    # A point whose spec differs (the PT series at 4 spp) is rendered; the rest reused.
    third = run_pareto(ParetoSpec(**{**TINY.__dict__, "pt_spp": [1, 2, 4]}), store, settings)
    assert sorted(renders) == sorted(f"{m}4" for m in PT_RUNS)
    assert [p.label for p in third.points if not p.reused] == [
        "paper's PT spp=4", "PT (throughput RR) spp=4", "pt-power (throughput RR) spp=4",
        "pt-spatial (throughput RR) spp=4"]
    # Speed-ups are against the strongest PT by default: the paper's PT points have one.
    assert third.baselines["speedups_against"] == "strongest PT"
    assert all(p.speedup_mrse.against == "strongest PT" for p in third.points
               if p.named_baseline == PAPER_PT)
    store.close()


def test_a_point_carries_exactly_the_run_result_of_its_stored_run(mi, data_dir):
    settings = Settings()
    store = open_store(settings)
    spec = ParetoSpec(**{**TINY.__dict__, "methods": ["pt"]})
    timed = run_pareto(spec, store, settings)
    # Without timing rounds the samples are the run's per-seed frame times, whose median
    # is the run's own seconds per frame: then every RunResult field is the run's.
    untimed = run_pareto(ParetoSpec(**{**spec.__dict__, "timing_rounds": 0}), store, settings)
    shared = set(RunResult.model_fields)
    for point, same in zip(timed.points, untimed.points, strict=True):
        row = RunResult.of(store.get_run(point.id))
        assert same.model_dump(include=shared) == row.model_dump(include=shared)
        # With rounds, only the time differs: the rounds' median; the run's is kept.
        assert point.model_dump(include=shared - {"seconds_per_frame"}) \
            == row.model_dump(include=shared - {"seconds_per_frame"})
        assert point.run_seconds_per_frame == row.seconds_per_frame
        assert point.seconds_per_frame == float(np.median(point.timing_samples))
        assert same.reused and same.id == point.id
    store.close()


def test_the_point_key_changes_with_everything_that_determines_a_run(monkeypatch):
    import jobs.protocol.spec as spec_module

    def prepared(fingerprint="scene", reference="ref", device="cpu"):
        return SimpleNamespace(scene=SimpleNamespace(fingerprint=fingerprint),
                               reference=SimpleNamespace(key=reference),
                               device={"device_key": device})

    spec = run_spec(TINY, plan(TINY)[0][0][0])
    key = point_key(spec, prepared())
    assert point_key(run_spec(TINY, plan(TINY)[0][0][0]), prepared()) == key
    others = [point_key(spec, prepared(fingerprint="edited")),
              point_key(spec, prepared(reference="other")),
              point_key(spec, prepared(device="gpu")),
              point_key(spec.model_copy(update={"frames": 2}), prepared()),
              point_key(spec.model_copy(update={"spp": 2}), prepared())]
    versions = spec_module.versions_of
    monkeypatch.setattr(spec_module, "versions_of", lambda method: {
        **versions(method), "estimator_version": versions(method)["estimator_version"] + 1})
    others.append(point_key(spec, prepared()))               # a new estimator version
    assert len({key, *others}) == len(others) + 1
