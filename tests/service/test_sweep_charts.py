"""GET /api/v1/charts/sweeps/{id} says what a sweep swept and draws a parameter sweep
against its values: the scene page headed every sweep 'Adaptive equal-bias sweep' and
drew a sweep over sph_c against % indirect-radiance bounces."""

from __future__ import annotations

from jobs.protocol.versions import current_estimator_versions
from metrics import METRIC_VERSION


def _stored_sweep(store, kind: str, result: dict) -> int:
    sweep = store.start_sweep(key=f"k-{kind}", kind=kind, scene_name="cornell-box",
                              scene_fingerprint="f", spec={}, result={}, device_key="test",
                              estimator_versions=current_estimator_versions(),
                              metric_version=METRIC_VERSION)
    store.finish_sweep(sweep.id, status="succeeded", result=result, finished_at=None)
    return sweep.id


def _row(**values) -> dict:
    return {"series": "NIRC", "ir_bounces_pct": 10.0, "mrse": 0.1, "flip": 0.3,
            "rbias2": 0.01, "rvar": 0.05, "ms_frame": 20.0, "eps": None, "value": None,
            **values}


def test_a_parameter_sweep_is_titled_and_drawn_against_its_values(api_and_store):
    http, store = api_and_store
    swept = _stored_sweep(store, "parameter", {
        "parameter": "sph_c", "rows": [_row(value=0.01, mrse=0.2), _row(value=0.1)]})
    eps = _stored_sweep(store, "eps", {"rows": [_row(eps=0.1), _row(eps=0.5, mrse=0.2)]})
    answers = {kind: http.get(f"/api/v1/charts/sweeps/{sweep_id}").json()
               for kind, sweep_id in (("parameter", swept), ("eps", eps))}
    assert answers["parameter"]["title"] == "Sweep over sph_c"
    assert answers["eps"]["title"] == "Adaptive equal-bias sweep"
    x = {kind: answer["charts"][0]["encoding"]["x"] for kind, answer in answers.items()}
    assert (x["parameter"]["field"], x["parameter"]["title"]) == ("swept", "sph_c")
    assert (x["eps"]["field"], x["eps"]["title"]) == ("pct", "indirect-radiance bounces (%)")
