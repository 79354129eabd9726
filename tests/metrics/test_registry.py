"""The metric registry: stored keys and verdict names unchanged, every consumer generated
from it, and PSNR of the tone-mapped image added by one entry (known values)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from metrics.errors import PSNR_MAX_DB, psnr_tonemapped
from metrics.quality import ERROR_METRICS, METRIC_KEYS, withhold
from metrics.registry import BY_NAME, LISTED, METRICS, Aggregate, per_seed_values, row_values


def srgb(x: float) -> float:
    """The sRGB encoding (IEC 61966-2-1), by hand."""
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


# ---- PSNR of the tone-mapped image ----

def test_psnr_of_identical_images_is_the_cap():
    image = np.random.default_rng(1).random((4, 5, 3), dtype=np.float32)
    assert psnr_tonemapped(image, image) == PSNR_MAX_DB == 100.0
    # Above 1 both clamp to 1: identical as displayed.
    assert psnr_tonemapped(np.full((2, 2, 3), 2.0), np.ones((2, 2, 3))) == PSNR_MAX_DB


def test_psnr_of_a_constant_display_offset_is_hand_computed():
    black = np.zeros((3, 3, 3), dtype=np.float32)
    # Linear 0.001 is on the sRGB linear segment: displayed 0.01292 against 0.
    assert psnr_tonemapped(black + 0.001, black) == pytest.approx(
        20 * math.log10(1 / 0.01292), rel=1e-5)   # 37.775 dB
    assert 20 * math.log10(1 / 0.01292) == pytest.approx(37.7747, abs=1e-4)
    # Grey 0.5 vs 0.25 through the sRGB curve: one offset d, PSNR = -20 log10 d.
    d = srgb(0.5) - srgb(0.25)
    assert psnr_tonemapped(black + 0.5, black + 0.25) == pytest.approx(
        -20 * math.log10(d), rel=1e-5)


def test_psnr_skips_nonfinite_pixels_and_is_none_without_any():
    ref = np.zeros((2, 2, 3), dtype=np.float32)
    test = ref + 0.001
    test[0, 0, 1] = np.nan
    assert psnr_tonemapped(test, ref) == pytest.approx(20 * math.log10(1 / 0.01292), rel=1e-5)
    assert psnr_tonemapped(np.full((2, 2, 3), np.inf), ref) is None


def test_psnr_entry_is_one_declaration():
    psnr = BY_NAME["psnr"]
    assert psnr.direction == "higher" and psnr.unit == "dB"
    assert psnr.aggregate is Aggregate.MEAN and (psnr.key, psnr.seed_key) == ("psnr_mean", "psnr")
    assert psnr.field == "psnr" and psnr.better(40.0, 30.0) and not psnr.better(30.0, 40.0)
    ref = np.zeros((2, 2, 3), dtype=np.float32)
    assert per_seed_values(ref + 0.001, ref) == {"psnr": psnr_tonemapped(ref + 0.001, ref)}
    # The quality verdict withholds it under its name, per seed and aggregated.
    assert "psnr" in ERROR_METRICS
    assert withhold({"psnr": 30.0, "psnr_mean": 30.0, "mse": 1.0}, ["psnr"]) == {
        "psnr": None, "psnr_mean": None, "mse": 1.0}


# ---- The registry keeps what is stored and served ----

def test_stored_keys_and_verdict_names_are_unchanged():
    stored = {m.name: m.key for m in METRICS}
    assert stored == {"mse": "mse_mean", "mrse": "mrse_mean", "flip_hdr": "flip_hdr_mean",
                      "flip_ldr": "flip_ldr_mean", "rbias2": "rbias2", "rvar": "rvar",
                      "rbias2_per_cache": "rbias2_per_cache_mean", "efficiency": "efficiency",
                      "psnr": "psnr_mean", "v_rel": "v_rel_mean",
                      **{f"denoised_{m}_{f}": f"denoised_{m}_{f}_mean" for f in ("frame", "accum")
                         for m in ("mrse", "flip")}}
    # The denoised errors are withheld with the raw error they denoise, V_rel with rVar.
    assert METRIC_KEYS == {"mse": ("mse",),
                           "mrse": ("mrse", "denoised_mrse_frame", "denoised_mrse_accum"),
                           "flip": ("flip_hdr", "flip_ldr", "denoised_flip_frame",
                                    "denoised_flip_accum"),
                           "rbias2": ("rbias2", "noise_floor"), "rvar": ("rvar", "v_rel"),
                           "efficiency": ("efficiency",),
                           "psnr": ("psnr",)}
    assert [m.field for m in LISTED] == ["mrse", "flip", "rbias2", "rvar", "psnr"]
    assert [m.name for m in METRICS if m.needs_k2] == ["rbias2", "rvar"]
    assert {m.name for m in METRICS if m.direction == "higher"} == {"efficiency", "psnr"}


def test_result_rows_and_api_fields_come_from_the_registry():
    from jobs.protocol.results import ReportRow
    from jobs.views.plots import _SWEEP_PANELS
    from service.api.schemas import RunOut
    from service.tables import SWEEP_COLUMNS

    served = {"mrse", "mrse_ci95", "rbias2", "rvar", "flip", "psnr"}
    assert served <= set(RunOut.model_fields)
    assert served <= set(ReportRow.model_fields)   # the report's JSON keys stay
    # The sweep figure keeps the paper's four panels (PSNR is not one of Fig. 13's).
    assert [(key, log) for key, _, log, _ in _SWEEP_PANELS] == [
        ("mrse", True), ("flip", False), ("rbias2", True), ("rvar", True)]
    assert {key for key, _ in SWEEP_COLUMNS} >= {"mrse", "flip", "rbias2", "rvar", "psnr"}
    stored = {"mrse_mean": 0.5, "mrse_ci95": (0.4, 0.6), "flip_hdr_mean": 0.2, "rbias2": 0.1,
              "rbias2_ci95": [-0.01, 0.2], "rbias2_ci_note": "how", "rbias2_basis": "per cache",
              "psnr_mean": 31.0}
    assert row_values(stored) == {"mrse": 0.5, "mrse_ci95": [0.4, 0.6], "flip": 0.2,
                                  "rbias2": 0.1, "rbias2_ci95": [-0.01, 0.2],
                                  "rbias2_ci_note": "how", "rvar": None, "rvar_ci95": None,
                                  "rvar_ci_note": None, "psnr": 31.0,
                                  "mrse_ci_note": "95 % interval of the mean, as stored",
                                  "below_noise_floor": [], "within_noise": ["rbias2"],
                                  "rbias2_basis": "per cache", "bias_verdict": "within noise"}
    # A run stored before rBias² had an interval says so; one above 0 is biased.
    old = row_values({"rbias2": 0.1})
    assert old["rbias2_ci95"] is None and "before" in old["rbias2_ci_note"]
    assert row_values({**stored, "rbias2_ci95": [0.01, 0.2]})["bias_verdict"] == "biased"


def test_the_registry_is_served_as_json():
    served = json.loads(json.dumps([m.to_json() for m in METRICS]))
    psnr = next(m for m in served if m["name"] == "psnr")
    assert psnr["direction"] == "higher" and psnr["field"] == "psnr" and psnr["unit"] == "dB"
    mrse = next(m for m in served if m["name"] == "mrse")
    assert mrse["ci_field"] == "mrse_ci95" and mrse["log_axis"] and mrse["sweep_plot"]


def test_readme_metric_table_is_generated_from_the_registry():
    from pathlib import Path

    from metrics.registry import METRICS, metric_table

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    begin, end = "<!-- metrics:begin -->\n", "\n<!-- metrics:end -->"
    assert begin in readme and end in readme, "README.md lost the metric-table markers"
    table = readme[readme.index(begin) + len(begin):readme.index(end)]
    assert table == metric_table(), ("README.md's metric table is stale: replace it with "
                                     "the output of `python -m metrics.registry`")
    assert all(f"`{m.key}`" in table for m in METRICS)
