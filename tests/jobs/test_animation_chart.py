"""The Vega-Lite spec of the animated runs' chart (jobs/views/animation_chart.py): its
rules sit at the frames where the drawn error jumps, with what changed; one line and
band per run in distinct colours; the recovery rows."""

from __future__ import annotations

from typing import Any

from jobs.views.animation_chart import animated_view, frame_error_chart
from jobs.views.chart_styles import FAMILY_COLOURS
from tests.jobs.animation_factories import animation_metrics

#: Errors that double at each change and settle within ~2 frames, noise 5 % per seed.
SHAPE = {"steady": 0.1, "jump": 1.0, "decay_frames": 1.0, "noise": 0.05}


def runs(**changed: Any) -> list[dict[str, Any]]:
    """pt and grid-cache on many-lights-switch (changes at 6 and 12), 18 frames."""
    return [{"id": i + 1, "method": method, "label": method,
             "animation": {**animation_metrics("many-lights-switch", 18, seed=i, **SHAPE),
                           **changed}}
            for i, method in enumerate(("pt", "grid-cache"))]


def layers(spec: dict[str, Any], mark: str) -> list[dict[str, Any]]:
    return [layer for layer in spec["layer"]
            if (layer["mark"]["type"] if isinstance(layer["mark"], dict) else layer["mark"])
            == mark]


def values(layer: dict[str, Any]) -> list[dict[str, Any]]:
    return layer["data"]["values"]


def rules_at_jumps(spec: dict[str, Any]) -> bool:
    """Every rule sits where each drawn line rises most within two frames of it."""
    rows = values(layers(spec, "line")[0])
    for rule in values(layers(spec, "rule")[0]):
        k = rule["frame"]
        for series in {row["series"] for row in rows}:
            curve = {row["frame"]: row["value"] for row in rows if row["series"] == series}
            rise = {f: curve[f] - curve[f - 1] for f in range(k - 2, k + 3)}
            if max(rise, key=rise.get) != k:
                return False
    return True


def test_rules_mark_the_change_frames_where_the_error_jumps_with_their_labels():
    spec = frame_error_chart(runs())
    rules = values(layers(spec, "rule")[0])
    assert [(r["frame"], r["label"]) for r in rules] == [(6, "8 lights off"), (12, "8 lights on")]
    assert values(layers(spec, "text")[0]) == rules          # each rule labelled
    assert rules_at_jumps(spec)
    # A planted off-by-one: the changes stored one frame late are rejected.
    late = frame_error_chart(runs(change_frames=[7, 13]))
    assert [r["frame"] for r in values(layers(late, "rule")[0])] == [7, 13]
    assert not rules_at_jumps(late)


def test_one_line_and_band_per_run_in_its_family_colour():
    spec = frame_error_chart(runs())
    colours = layers(spec, "line")[0]["encoding"]["color"]["scale"]
    assert dict(zip(colours["domain"], colours["range"], strict=True)) == {
        "pt": FAMILY_COLOURS["pt"], "grid-cache": FAMILY_COLOURS["grid-cache"]}
    band = layers(spec, "area")[0]
    assert band["encoding"]["y2"]["field"] == "hi"
    assert all(r["lo"] < r["value"] < r["hi"] for r in values(band))


def test_recovery_rows_name_each_change_and_a_run_without_curve_gets_no_chart():
    view = animated_view(runs())
    rows = view["recoveries"]
    assert [(r["run"], r["change_frame"], r["label"]) for r in rows] == [
        (1, 6, "8 lights off"), (1, 12, "8 lights on"),
        (2, 6, "8 lights off"), (2, 12, "8 lights on")]
    assert all(r["low"] <= r["frames"] <= r["high"] for r in rows)
    assert animated_view([{"id": 1, "method": "pt", "label": "pt", "animation": None}]) is None
    empty = animated_view([{"id": 1, "method": "pt", "label": "pt", "animation": {
        "change_frames": [8], "frame_mrse": None, "recovery": None,
        "note": "a frame's error is NaN or infinite: no mean over seeds is taken"}}])
    assert empty["chart"] is None and "NaN" in empty["note"]


def test_a_change_after_the_last_frame_draws_no_rule():
    spec = frame_error_chart([{"id": 1, "method": "pt", "label": "pt", "animation":
                               animation_metrics("cornell-box-sudden", 4, **SHAPE, seed=0)}])
    assert layers(spec, "rule") == []
