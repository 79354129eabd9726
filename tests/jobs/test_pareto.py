"""The pareto command's plan (read from the method registry), its evaluation of measured
points (fronts, speed-ups) and its plot, without rendering."""

from __future__ import annotations

import pytest

from jobs.protocol.pareto import PARETO_METRICS, ParetoSpec, _evaluate, interleave, plan
from jobs.protocol.plots import plot_pareto
from renderers.methods import BASELINE, METHODS


def _series_by_name(spec: ParetoSpec) -> dict[str, list]:
    series, _ = plan(spec)
    return {points[0].series: points for points in series}


def test_the_plan_reads_knobs_and_comparison_runs_from_the_registry():
    series, skipped = plan(ParetoSpec(scene="cornell-box"))
    baseline = [s for s in series if s[0].method == BASELINE]
    assert len(baseline) == 1 and [p.spp for p in baseline[0]] == [1, 2, 4, 8, 16]
    planned = {p.method for points in series for p in points}
    for name, method in METHODS.items():
        if name == BASELINE:
            continue
        knob_series = [s for s in series if s[0].method == name and len(s) > 1]
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
    assert "pretrain_frames" not in by_name["PT"][0].params


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
    assert [p.label for p in interleave(series)] == [
        "PT spp=1", "NIRC nc=1", "NIRC unbiased", "PT spp=2", "NIRC nc=2", "PT spp=4"]


@pytest.mark.parametrize("changes, fragment", [
    ({"methods": ["nirc"]}, "baseline"),
    ({"pt_spp": [4, 4]}, "at least two"),
    ({"knob_values": {"nrc": [1, 2]}}, "no equal-time knob"),
    ({"knob_values": {"pt": [1, 2]}}, "--pt-spp"),
    ({"methods": ["pt", "no-such"]}, "unknown method"),
    ({"knob_values": {"nirc": [300]}}, "nc"),
    ({"pt_spp": [1, 1 << 17]}, "spp"),
])
def test_bad_plans_are_errors_before_anything_renders(changes, fragment):
    with pytest.raises(ValueError, match=fragment):
        plan(ParetoSpec(scene="cornell-box", **changes))


def _point(series: str, seconds: float, mrse: float | None, flip: float,
           baseline: bool = False) -> dict:
    return {"series": series, "label": f"{series} {seconds}", "baseline": baseline,
            "seconds_per_frame": seconds, "seconds_spread": [0.9 * seconds, 1.1 * seconds],
            "timing_samples": [seconds, 0.95 * seconds, 1.05 * seconds],
            "mrse": mrse, "mrse_per_seed": [mrse, mrse] if mrse is not None else [None, None],
            "flip": flip, "flip_per_seed": [0.98 * flip, 1.02 * flip]}


def test_fronts_and_speed_ups_of_measured_points():
    points = [_point("PT", 0.01 * n, 0.4 / n, 0.3 / n ** 0.5, baseline=True)
              for n in (1, 2, 4, 8)]
    points += [_point("NIRC", 0.02, 0.05, 0.2),       # PT reaches MRSE 0.05 at 0.08 s: 4x
               _point("NIRC", 0.5, 0.02, 0.01),       # below PT's range: '>'
               _point("NRC", 0.05, None, 0.5)]        # MRSE withheld: n/a
    _evaluate(points, resamples=200)
    # NIRC at 0.02 s beats PT at 2, 4 and 8 spp (as fast or faster, less error).
    assert [p["front_mrse"] for p in points] == [True, False, False, False, True, True, False]
    assert points[4]["speedup_mrse"]["relation"] == "="
    assert points[4]["speedup_mrse"]["value"] == pytest.approx(4.0)
    lo, hi = points[4]["speedup_mrse"]["ci95"]
    assert lo <= 4.0 <= hi
    assert points[5]["speedup_mrse"]["relation"] == ">"
    assert points[5]["speedup_mrse"]["value"] == pytest.approx(0.08 / 0.5)
    assert points[6]["speedup_mrse"]["relation"] == "n/a" and "MRSE" in points[6]["speedup_mrse"]["note"]
    assert points[6]["speedup_flip"]["relation"] == "<"
    assert all("speedup_mrse" not in p for p in points[:4])


def test_the_plot_draws_every_metric(tmp_path):
    points = [_point("PT", 0.01 * n, 0.4 / n, 0.3, baseline=True) for n in (1, 2)]
    points.append(_point("NIRC", 0.02, 0.05, 0.2))
    _evaluate(points, resamples=100)
    for metric in PARETO_METRICS:
        path = plot_pareto(points, metric.field, metric.label, tmp_path / f"{metric.field}.png",
                           "test")
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
