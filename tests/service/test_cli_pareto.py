"""``nirc-bench pareto`` end to end, in subprocesses: the JSON, the files, the errors."""

from __future__ import annotations

import json
from collections.abc import Iterator
from concurrent.futures import Future

import pytest

from jobs.pareto.pareto import ParetoPoint
from tests.service.test_cli import assert_clean_error, run_cli, started_together

SMALL = ("pareto", "--scene", "cornell-box", "--res", "16", "--frames", "2", "--seeds", "2",
         "--ref-spp", "256", "--pretrain-frames", "0", "--timing-rounds", "2",
         "--resamples", "200")


def test_pareto_writes_the_points_fronts_speed_ups_and_plots(tmp_path):
    out = tmp_path / "out"
    # 1 and 16 spp: far enough apart in time that timing noise cannot make a PT
    # candidate's 16-spp point look no slower than its 1-spp point (which would leave
    # each candidate a single point and the envelope empty).
    # --allow-loaded: the test machine is shared, and a point timed loaded would be left
    # out of the fronts and speed-ups this test reads (what it checks is how they are made).
    args = (*SMALL, "--methods", "pt,nirc", "--pt-spp", "1,16", "--knob-values", "nirc=1,2",
            "--allow-loaded")
    proc = run_cli(*args, "--out", str(out), "--json", data_dir=tmp_path / "data")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert json.loads((out / "pareto.json").read_text())["points"] == result["points"]
    # Every point is the one public model (RunResult and the pareto columns).
    assert all(ParetoPoint.model_validate(p).model_dump(mode="json") == p
               for p in result["points"])
    for name in ("pareto_mrse.png", "pareto_flip.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    points = {p["label"]: p for p in result["points"]}
    pts = ("paper's PT", "PT (throughput RR)", "pt-power (throughput RR)",
           "pt-spatial (throughput RR)")
    assert set(points) == {*(f"{s} spp={n}" for s in pts for n in (1, 16)), "NIRC nc=1",
                           "NIRC nc=2", "NIRC unbiased"}
    assert len({p["id"] for p in points.values()}) == 11          # one stored run each
    assert result["work"]["points_rendered"] == 11
    assert not any(p["reused"] for p in points.values())
    # Speed-ups are against the strongest PT by default, whose envelope the JSON carries.
    assert result["spec"]["baseline"] == "strongest-pt"
    assert result["baselines"]["speedups_against"] == "strongest PT"
    assert {p["series"] for p in points.values() if p["baseline"]} == set(pts[1:])
    assert result["baselines"]["strongest-pt"]["envelope"]["mrse"]
    assert result["left_out"] == [] and result["spec"]["allow_loaded"]
    assert all(isinstance(p["loaded"], bool) for p in points.values())
    for point in points.values():
        # Two interleaved timing rounds; the time is their median.
        assert len(point["timing_samples"]) == 2
        lo, hi = point["seconds_spread"]
        assert lo <= point["seconds_per_frame"] <= hi
        assert len(point["mrse_per_seed"]) == 2 and point["mrse"] > 0
        assert isinstance(point["front_mrse"], bool) and isinstance(point["front_flip"], bool)
        if point["baseline"]:
            assert point["speedup_mrse"] is None
        else:
            speedup = point["speedup_mrse"]
            assert speedup["relation"] in ("=", ">", "<")
            assert speedup["value"] > 0 and len(speedup["ci95"]) == 2
            assert speedup["against"] == "strongest PT" and speedup["via"] in pts[1:]
    assert any(p["front_mrse"] for p in points.values())
    assert result["bootstrap"]["resamples"] == 200 and "percentile" in result["bootstrap"]["method"]

    # The same call again, against the paper's PT, reuses every stored run (the table
    # marks them '=') and prints the same errors; only the timing rounds are measured again.
    again = run_cli(*args, "--baseline", "paper-pt", data_dir=tmp_path / "data")
    assert again.returncode == 0, again.stderr
    assert "11 reused, 0 rendered now" in again.stdout
    assert "x paper's PT at equal MRSE" in again.stdout and "strongest PT (MRSE):" in again.stdout
    for point in points.values():
        assert f"{point['id']}=" in again.stdout
        assert f"{point['mrse']:.4g}" in again.stdout


BAD_ARGUMENTS = [
    (("--pt-spp", "4"), "at least two"),
    (("--pt-spp", "0,2"), ">= 1"),
    (("--pt-spp", "a,b"), "not a number"),
    (("--methods", "nirc"), "baseline"),
    (("--methods", "pt,bogus"), "unknown method"),
    (("--knob-values", "nrc=1,2"), "no equal-time knob"),
    (("--knob-values", "nirc=0,2"), ">= 1"),
    (("--knob-values", "nirc=300"), "nc"),
    (("--seeds", "1"), "seeds"),
    (("--project-res", "1920"), "WIDTHxHEIGHT"),
    (("--project-res", "0x1080"), "1..16384"),
    (("--project-res", "64x64", "--cost-res", "8"), "at least two --cost-res"),
    (("--baseline", "fastest-pt"), "unknown baseline 'fastest-pt': give paper-pt, strongest-pt"),
    (("--baseline", "NRC"), "single point"),
]


def _call(args: tuple[str, ...]) -> tuple[str, ...]:
    return ("pareto", "--scene", "cornell-box", *args)


@pytest.fixture(scope="module")
def error_calls(tmp_path_factory) -> Iterator[dict[tuple[str, ...], Future]]:
    yield from started_together([_call(args) for args, _ in BAD_ARGUMENTS],
                                tmp_path_factory.mktemp("errors"))


@pytest.mark.parametrize("args, fragment", BAD_ARGUMENTS)
def test_bad_pareto_arguments_are_clear_errors(error_calls, args, fragment):
    proc = error_calls[_call(args)].result()
    assert_clean_error(proc, fragment)
    assert proc.returncode == 2


def test_pareto_projects_each_point_from_its_cost_model(tmp_path):
    args = (*SMALL, "--res", "8", "--methods", "pt", "--pt-spp", "1,2",
            "--project-res", "64x48", "--cost-res", "8,16")
    proc = run_cli(*args, "--json", data_dir=tmp_path / "data")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["timing"]["cost_resolutions"] == [8, 16]
    for point in result["points"]:
        projection = point["projection"]
        assert (projection["width"], projection["height"]) == (64, 48)
        assert projection["label"].startswith("projection to 64x48 from ")
        stages = {s["stage"]: s for s in projection["stages"]}
        assert stages["render"]["size"] == 64 * 48 * point["spp"]
        lo, hi = projection["frame_ci"]
        assert lo <= projection["frame_s"] <= hi
        assert isinstance(point["probe_flags"], list)
    table = run_cli(*args, data_dir=tmp_path / "data").stdout
    # The header may wrap between its words: the table is wide.
    assert "ms/frame at 64x48" in table and "(projected)" in table
    assert "not a measurement" in table


def test_knob_values_name_one_method_or_every_method_with_a_knob():
    from jobs.pareto.plan import knob_methods
    from service.cli import _parse_knob_values

    assert _parse_knob_values(["1,4"]) == dict.fromkeys(knob_methods(), [1, 4])
    assert _parse_knob_values(["nirc=2:8:2"]) == {"nirc": [2, 4, 6, 8]}
