"""``nirc-bench runs`` and render reuse on a store of tiny real runs of two methods
(8x8 pixels, 2 frames of 1 spp): list, show, compare, export, names and tags, and
``apikey list``; in process (Typer's runner) to keep it fast."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import sys
from pathlib import Path
from unittest import mock

import pytest
from typer.testing import CliRunner

from jobs.protocol.provenance import git_commit
from service.cli import app, main

RENDER = ("render", "-s", "cornell-box", "--res", "8", "--spp", "1", "--frames", "2",
          "--seeds", "3", "--ref-spp", "16")


@pytest.fixture(scope="module")
def store_dir(tmp_path_factory, mi):
    """A data folder with runs 1 (pt, named and tagged), 2 (its --rerun), 3 (pt,
    max_depth 4, spp 2) and 4 (pt-power), and what the renders printed."""
    data = tmp_path_factory.mktemp("runs") / "data"
    saved = os.environ.get("NIRC_BENCH_GIT_COMMIT")
    os.environ["NIRC_BENCH_GIT_COMMIT"] = "0123456789abcdef"   # a clean commit: reusable
    git_commit.cache_clear()
    try:
        outputs = [cli(*RENDER, "--name", "baseline", "--tag", "exp=a", data=data),
                   cli(*RENDER, data=data),
                   cli(*RENDER, "--rerun", data=data),
                   cli(*RENDER[:-4], "--spp", "2", "--seeds", "3", "--ref-spp", "16",
                       "--max-depth", "4", data=data),
                   cli(*RENDER, "-m", "pt-power", data=data)]
    finally:
        if saved is None:
            os.environ.pop("NIRC_BENCH_GIT_COMMIT")
        else:
            os.environ["NIRC_BENCH_GIT_COMMIT"] = saved
        git_commit.cache_clear()
    return data, outputs


def cli(*args: str, data=None) -> str:
    result = CliRunner().invoke(app, [*args, *(["--data-dir", str(data)] if data else [])])
    assert result.exit_code == 0, (result.output, result.exception)
    return result.output


def cli_error(capsys, *args: str, data) -> str:
    """A user error: exit status 2 and one line on standard error (the console entry
    point's handling, as ``nirc-bench`` runs it)."""
    capsys.readouterr()
    with mock.patch.object(sys, "argv", ["nirc-bench", *args, "--data-dir", str(data)]), \
            pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    text = capsys.readouterr().err
    assert text.startswith("nirc-bench: error: ") and text.count("\n") == 1, text
    return text


def test_render_reuses_a_stored_run_and_says_so_until_rerun(store_dir):
    data, outputs = store_dir
    assert "reused" not in outputs[0]
    assert "reused run 1, stored" in outputs[1] and "commit 0123456789abcdef" in outputs[1]
    assert "timing flags" in outputs[1] and "--rerun" in outputs[1]
    assert "reused" not in outputs[2]
    ids = [row["id"] for row in json.loads(cli("runs", "list", "--json", data=data))]
    assert ids == [4, 3, 2, 1]      # the reused render stored nothing; --rerun stored run 2


def test_runs_list_filters_sorts_and_chooses_columns(store_dir, capsys):
    data, _ = store_dir

    def ids(*args: str) -> list[int]:
        return [row["id"] for row in json.loads(cli("runs", "list", "--json", *args,
                                                    data=data))]

    assert ids("--method", "pt-power") == [4]
    assert ids("--param", "max_depth=4") == [3]
    assert ids("--tag", "exp=a") == ids("--name", "baseline") == [1]
    assert ids("--commit", "0123", "--scene", "cornell-box", "--limit", "2") == [4, 3]
    assert ids("--since", "2000-01-01", "--until", "2001-01-01") == []
    rows = list(csv.DictReader(io.StringIO(cli(
        "runs", "list", "--csv", "--columns", "id,method,params.max_depth,spp,mrse",
        "--sort", "mrse", data=data))))
    assert list(rows[0]) == ["id", "method", "params.max_depth", "spp", "mrse"]
    mrse = [float(row["mrse"]) for row in rows]
    assert mrse == sorted(mrse) and len(rows) == 4
    assert {row["params.max_depth"] for row in rows if row["id"] == "3"} == {"4"}
    table = cli("runs", "list", data=data)
    assert "pt (max_depth 4)" in table and "pt-power" in table and "8²" in table
    more = cli("runs", "list", "--columns", "id,name,changed,seeds", data=data)
    assert "max_depth=4" in more and "baseline" in more
    wrong = cli_error(capsys, "runs", "list", "--columns", "id,mrsee", data=data)
    assert "unknown column 'mrsee'" in wrong and "params.NAME" in wrong


def test_runs_list_fits_120_columns_and_never_cuts_a_number(store_dir, monkeypatch):
    """A sweep point's long label and an MRSE above 1 ('1.…' at 100 columns before):
    the default columns fit 120 columns; at 100 the label wraps, no number is cut.
    Planted: numbers laid out like text are cut at 100 columns."""
    from rich.console import Console
    from sqlalchemy.orm.attributes import flag_modified

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.record.models import Run
    from service import runs_command

    data, _ = store_dir
    store = open_store(Settings(data_dir=data))

    def set_run(params: dict, metrics: dict) -> None:
        with store.session(write=True) as session:
            run = session.get(Run, 3)
            run.params, run.metrics = params, metrics
            flag_modified(run, "params")
            flag_modified(run, "metrics")

    def listed(width: int, *args: str) -> str:
        console = Console(width=width, record=True, emoji=False)
        monkeypatch.setattr(runs_command, "console", console)
        cli("runs", "list", *args, data=data)
        return console.export_text()

    with store.session() as session:
        saved = session.get(Run, 3).params, session.get(Run, 3).metrics
    long = {**saved[0], "rr_mode": "throughput", "rr_depth": 2, "rr_survival": 0.75,
            "sweep": {"eps": 0.35}}
    try:
        set_run(long, {**saved[1], "mrse_mean": 1.2345678})
        wide = listed(120)
        assert max(map(len, wide.splitlines())) <= 120
        assert "1.23" in wide and "…" not in wide
        rows = json.loads(cli("runs", "list", "--json", data=data))
        numbers = [f"{row['mrse']:.3g}" for row in rows]
        numbers += [f"{1e3 * row['seconds_per_frame']:.3g}" for row in rows]

        def whole(text: str) -> bool:   # every number on one line, uncut
            return "…" not in text and all(number in text for number in numbers)

        assert whole(listed(100)) and whole(listed(60))
        monkeypatch.setattr(runs_command, "NUMBER_COLUMNS", ())    # numbers laid out as text
        assert not whole(listed(60))
    finally:
        set_run(*saved)


def test_runs_list_intervals_read_to_3_digits_as_every_number(store_dir, monkeypatch):
    """docs/runs.md's column choice with MRSE's interval at 120 columns: the interval's
    ends read to 3 digits like the MRSE beside them (they read to 17 before), nothing is
    cut; CSV keeps every digit. Planted: a cell laid out as plain text (JSON) shows
    the 17 digits."""
    from rich.console import Console

    from service import runs_command

    data, _ = store_dir
    columns = "id,name,method_label,seeds,mrse,mrse_ci95,flip,ms,device_key"

    def listed() -> str:
        console = Console(width=120, record=True, emoji=False)
        monkeypatch.setattr(runs_command, "console", console)
        cli("runs", "list", "--columns", columns, data=data)
        return console.export_text()

    row = json.loads(cli("runs", "list", "--json", data=data))[0]
    low, high = row["mrse_ci95"]
    shown = f"[{low:.3g}, {high:.3g}]"
    text = listed()
    assert shown in text and repr(low) not in text and "…" not in text
    assert max(map(len, text.splitlines())) <= 120
    exported = cli("runs", "list", "--columns", columns, "--csv", data=data)
    assert repr(low) in exported
    monkeypatch.setattr(runs_command, "_cell",
                        lambda _column, value, _below: runs_command._text(value))
    assert shown not in listed()


def test_runs_show_prints_parameters_provenance_and_reference(store_dir, capsys):
    data, _ = store_dir
    text = cli("runs", "show", "3", data=data)
    for fragment in ("parameters", "max_depth", "rr_survival", "provenance",
                     "0123456789abcdef", "reference", "integrator", "per seed"):
        assert fragment in text
    assert "rBias² 95% CI" in text and "rVar 95% CI" in text and "jackknife" in text
    detail = json.loads(cli("runs", "show", "3", "--json", data=data))
    assert detail["reference"]["max_depth"] == 4 and len(detail["per_seed"]) == 3
    assert "no run 99" in cli_error(capsys, "runs", "show", "99", data=data)


def test_runs_compare_names_what_differs_and_refuses_other_metric_versions(store_dir, capsys):
    data, _ = store_dir
    comparison = json.loads(cli("runs", "compare", "1", "3", "--json", data=data))
    assert comparison["differences"]["params.max_depth"] == [-1, 4]
    assert comparison["differences"]["spp"] == [1, 2]
    assert "reference" in comparison["differences"]     # max_depth 4: another reference
    mrse = next(m for m in comparison["deltas"][0]["metrics"] if m["metric"] == "mrse")
    assert mrse["delta"] == pytest.approx(mrse["value"] - mrse["baseline"])
    low, high = mrse["delta_ci95"]      # 3 seeds each: a Welch interval around the change
    assert low < mrse["delta"] < high
    assert mrse["differs"] == (not low <= 0 <= high)
    # rBias² and rVar: Welch over the stored jackknife values, whose means are the values.
    for name in ("rbias2", "rvar"):
        delta = next(m for m in comparison["deltas"][0]["metrics"] if m["metric"] == name)
        assert delta["delta_ci95"] and "Welch" in delta["interval_note"]
        assert delta["differs"] is not None
    run1 = comparison["runs"][0]
    assert run1["rbias2_basis"] == "pooled" and run1["bias_verdict"] in ("biased",
                                                                         "within noise")
    assert run1["rbias2_ci95"][0] <= run1["rbias2"] <= run1["rbias2_ci95"][1]
    standing = comparison["standings"][0]
    assert standing["ms_per_frame"] == pytest.approx(1e3 * run1["seconds_per_frame"])
    low, high = standing["efficiency_ci95"]
    assert low < standing["efficiency"] < high and standing["verdict"] == run1["verdict"]
    table = cli("runs", "compare", "1", "3", data=data)
    for fragment in ("params.max_depth", "ms / frame", "efficiency", "differs",
                     "quality verdict"):
        assert fragment in table

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.record.models import Run

    store = open_store(Settings(data_dir=data))
    with store.session(write=True) as session:
        stored_version = session.get(Run, 2).metric_version
        session.get(Run, 2).metric_version = 1
    try:
        refused = cli_error(capsys, "runs", "compare", "1", "2", data=data)
    finally:
        with store.session(write=True) as session:
            session.get(Run, 2).metric_version = stored_version
    assert "different metric definitions" in refused and "run 2: v1" in refused


def test_runs_compare_says_which_parameters_a_method_does_not_have(store_dir):
    """Beside a nirc run, pt's nc reads '- (not a pt parameter)' (it read 'None', like a
    value); a parameter both have keeps its value."""
    from rich.console import Console

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.views.comparison import compare_runs
    from service.tables import comparison_table

    data, _ = store_dir
    store = open_store(Settings(data_dir=data))
    comparison = compare_runs([store.get_run(1), store.get_run(3)])
    nirc = comparison.runs[1].model_copy(update={"method": "nirc",
                                                 "params": {**comparison.runs[1].params,
                                                            "nc": [4]}})
    comparison = comparison.model_copy(update={
        "runs": [comparison.runs[0], nirc],
        "differences": {**comparison.differences, "params.nc": [None, [4]]}})
    console = Console(width=300, record=True)
    console.print(comparison_table(comparison))
    rows = {line.split("│")[1].strip(): line for line in console.export_text().splitlines()
            if line.startswith("│")}
    assert "- (not a pt parameter)" in rows["params.nc"] and "None" not in rows["params.nc"]
    assert "[4]" in rows["params.nc"]
    assert "- (not a" not in rows["params.max_depth"]


def test_runs_compare_does_not_call_loaded_timings_comparable(store_dir):
    """Run 2 marked as timed on a loaded machine: the comparison names it and its flag;
    unloaded, the same runs are comparable (planted: the flag ignored)."""
    data, _ = store_dir
    from sqlalchemy.orm.attributes import flag_modified

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.record.models import Run

    def note() -> tuple[str, list[str]]:
        found = json.loads(cli("runs", "compare", "1", "2", "--json", data=data))
        return found["note"], found["standings"][1]["timing_flags"]

    store = open_store(Settings(data_dir=data))

    def set_load(loads: dict[int, dict]) -> None:
        with store.session(write=True) as session:
            for run_id, load in loads.items():
                run = session.get(Run, run_id)
                run.timings = {**run.timings, "load": load}
                flag_modified(run, "timings")

    with store.session() as session:
        saved = {run_id: session.get(Run, run_id).timings.get("load") for run_id in (1, 2)}
    try:
        set_load({1: {"loaded": False}, 2: {"loaded": False}})
        unloaded = note()
        set_load({2: {"loaded": True, "reasons": ["load 9 on 2 cores"]}})
        loaded = note()
    finally:
        set_load(saved)
    assert unloaded[0].startswith("timings comparable") and unloaded[1] == []
    assert loaded[0].startswith("timings not comparable: run(s) 2 ")
    assert loaded[1] == ["loaded: load 9 on 2 cores"]


def test_runs_export_writes_every_stored_file(store_dir, capsys, tmp_path):
    data, _ = store_dir
    from jobs.record.artifacts import ArtifactStore
    from jobs.record.config import Settings
    from jobs.record.db import open_store

    settings = Settings(data_dir=data)
    run = open_store(settings).get_run(3)
    out = tmp_path / "export"
    printed = cli("runs", "export", "3", "--out", str(out), data=data)
    expected = {"reference.exr", "reference.variance.exr", "reference_preview.png",
                "convergence.png", "summary.json", "preview_seed0.png",
                "error_map_seed0.png", "rel_bias_map.exr", "rel_variance_map.exr",
                *(f"image_seed{k}.exr" for k in range(3))}
    assert {path.name for path in out.iterdir()} == expected
    # Each line names a file as the folder does ('convergence: ...' before).
    listed = dict(line.split(": ", 1) for line in printed.splitlines())
    assert set(listed) == expected and all(out / name == Path(path)
                                           for name, path in listed.items())

    def sha(path) -> str:
        return hashlib.sha256(path.read_bytes()).hexdigest()

    seeds = {s.id: s.seed for s in run.seed_results}
    artifacts = ArtifactStore(settings.artifacts_dir)
    for artifact in run.artifacts:
        seed = seeds.get(artifact.seed_result_id)     # None: the run's own (its maps)
        name = artifact.kind if seed is None else f"{artifact.kind}_seed{seed}"
        assert sha(out / f"{name}{artifacts.path_of(artifact.path).suffix}") == artifact.sha256
    assert sha(out / "reference.exr") == sha(settings.references_dir / run.reference.image_path)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["run_id"] == 3 and summary["result"]["params"]["max_depth"] == 4
    assert summary["spec"]["spp"] == 2 and len(summary["per_seed"]) == 3
    assert "is a file" in cli_error(capsys, "runs", "export", "3", "--out", str(out / "summary.json"),
                              data=data)


def test_runs_tag_and_apikey_list(store_dir):
    data, _ = store_dir
    assert "name paper-fig, tags exp=b" in cli("runs", "tag", "4", "--name", "paper-fig",
                                                "--tag", "exp=b", data=data)
    assert "tags -" in cli("runs", "tag", "4", "--untag", "exp", data=data)
    cli("apikey", "create", "--name", "ci-bot", data=data)
    keys = json.loads(cli("apikey", "list", "--json", data=data))
    assert [k["name"] for k in keys] == ["ci-bot"] and keys[0]["revoked"] is None
    assert "ci-bot" in cli("apikey", "list", data=data)


def test_intervals_and_signs_are_honest_in_tables_and_json(store_dir, tmp_path):
    """Two seeds: no MRSE interval, and the table says why; a negative noise-corrected
    rBias² reads 'below the noise floor'; pt has no per-cache rows."""
    data, _ = store_dir
    two = tmp_path / "two"
    text = cli(*RENDER[:-4], "--seeds", "2", "--ref-spp", "16", data=two)
    assert "no interval: 2 seeds (an interval needs 3 or more)" in text
    assert "per cache" not in text
    row = json.loads(cli("runs", "list", "--json", data=two))[0]
    assert row["mrse_ci95"] is None and "2 seeds" in row["mrse_ci_note"]

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.record.models import Run

    store = open_store(Settings(data_dir=two))
    with store.session(write=True) as session:
        run = session.get(Run, 1)
        run.metrics = {**run.metrics, "rbias2": -0.00123}
    assert "below the noise floor (-0.00123)" in cli("runs", "show", "1", data=two)
    row = json.loads(cli("runs", "list", "--json", data=two))[0]
    assert row["below_noise_floor"] == ["rbias2"] and row["rbias2"] == -0.00123
    # `runs list` marks it too (it printed a plain -0.00123); CSV keeps the number.
    listed = cli("runs", "list", "--columns", "id,rbias2,rvar", data=two)
    assert "<0 (noise, -0.00123)" in listed
    assert "-0.00123" in cli("runs", "list", "--columns", "id,rbias2", "--csv", data=two)
    with store.session(write=True) as session:   # a positive one stays a plain number
        run = session.get(Run, 1)
        run.metrics = {**run.metrics, "rbias2": 0.00123}
    listed = cli("runs", "list", "--columns", "id,rbias2,rvar", data=two)
    assert "0.00123" in listed and "noise" not in listed
    # rBias² + rVar vs MRSE: a note under a cache method's run (per-cache rBias²) only.
    note = "rVar and MRSE are pooled over seeds: rBias² + rVar = MRSE - ref floor"
    assert note not in cli("runs", "show", "1", data=two)       # pt: pooled, they add up
    with store.session(write=True) as session:
        run = session.get(Run, 1)
        run.metrics = {**run.metrics, "rbias2_basis": "per cache", "rbias2": 0.003,
                       "rbias2_pooled": 0.001}
    shown = cli("runs", "show", "1", data=two)
    (line,) = [line for line in shown.splitlines() if note in line]   # one line
    assert "(rBias² - pooled rBias² = 0.002)" in line and len(line) <= 220


def test_tables_say_what_ran_and_methods_lists_parameters(store_dir, capsys):
    data, _ = store_dir
    from jobs.protocol.labels import run_label

    assert run_label("nirc", {"estimator": "biased", "termination": "sph", "nc": [8],
                              "max_depth": -1}) == "nirc (sph, N_c 8)"
    assert run_label("pt", {"max_depth": -1, "rr_survival": 0.9}) == "pt"
    text = cli("runs", "show", "3", data=data)
    assert "cornell-box / pt (max_depth 4)" in text
    assert "path, 16 spp, max_depth 4 (reference" in text     # the reference's settings
    assert json.loads(cli("runs", "list", "--json", "--param", "max_depth=4",
                          data=data))[0]["method_label"] == "pt (max_depth 4)"

    listed = cli("methods")
    assert all(name in listed for name in ("pt", "nirc", "nrc", "nvc-env"))
    nirc = json.loads(cli("methods", "nirc", "--json"))
    params = {p["name"]: p for p in nirc["params"]}
    assert params["estimator"]["default"] == "biased" and "bth" in params["termination"]["type"]
    assert "surface" in nirc["needs"] and nirc["knob"] == "nc"
    wrong = cli_error(capsys, "render", "-s", "cornell-box", "-m", "nirc", "-p", "ncc=4",
                      data=data)
    assert "ncc" in wrong and "nirc's parameters are" in wrong and "termination" in wrong


def test_progress_lines_in_any_output_and_sweep_rows_collapse_only_when_they_render_alike(
        store_dir):
    """Not a terminal (the test runner): renders print plain progress lines. The sweep
    table shows points that render the same images (equal render keys) once, and says
    so; points whose v1 masks are saturated alike but whose N_c differ stay rows."""
    from rich.console import Console

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.sweeps.sweep import SweepResult, point_row
    from service.tables import sweep_table

    data, outputs = store_dir
    assert "progress: reference" in outputs[0] and "progress: seed 3/3 2/2" in outputs[0]
    assert outputs[0].count("progress: seed 1/3 2/2") == 1      # a finished stage: once
    run = open_store(Settings(data_dir=data)).get_run(1)
    points = {0.05: (40.0, "a", 1), 0.1: (80.0, "b", 1), 0.15: (80.0, "c", 1),
              0.2: (100.0, "d", 1), 0.5: (100.0, "d", 1), 1.0: (100.0, "d", 1)}
    equal_time = {0.6: (100.0, "e", 1), 0.8: (100.0, "f", 2), 1.0: (100.0, "g", 4)}

    def rows(series, table):
        return [point_row(series, eps, run).model_copy(update={
            "mask_pct": pct, "render_key": key, "nc": nc}) for eps, (pct, key, nc) in table.items()]

    work = dict.fromkeys(("reference_rendered", "snapshots_trained", "snapshots_reused",
                          "points_rendered", "points_reused", "calibrations"), 0)
    result = SweepResult(sweep_id=1, key="k", kind="eps", scene="cornell-box",
                         device_key=run.device_key, rows=rows("nirc", points)
                         + rows("nirc-equal-time", equal_time), skipped=[], work=work)
    console = Console(width=400, record=True)
    console.print(sweep_table(result))
    text = console.export_text()
    assert "0.2–1" in text and "0.15" in text     # an unsaturated repeat stays a row
    assert "eps 0.2 to 1 shown as one row: these 3 points render the same images" in text
    series = [line.split("│")[1].strip() for line in text.splitlines() if line.startswith("│")]
    assert series.count("NIRC") == 4
    # Planted (the table's old rule merged saturated masks): N_c 1, 2 and 4 stay apart.
    assert series.count("NIRC equal time") == 3
    assert "0.6–1" not in text
    header = next(line for line in text.splitlines() if "series" in line)
    assert "value" not in header     # a parameter sweep's column only


def test_user_errors_are_one_line_and_text_is_never_markup(tmp_path, capsys):
    """Option checks, a data folder that is a file, and 'a:b:step' (an emoji code to rich)
    in help and errors: one line, exit status 2, the text as written."""
    data = tmp_path / "data"
    assert "Invalid value for '--res'" in cli_error(
        capsys, "render", "-s", "cornell-box", "--res", "0", data=data)
    assert "No such command 'nope'" in cli_error(capsys, "nope", data=data)
    a_file = tmp_path / "notes.md"
    a_file.write_text("not a folder")
    assert "is a file, not a folder" in cli_error(capsys, "runs", "list", data=a_file)
    assert "'1:b:2'" in cli_error(capsys, "sweep", "-s", "cornell-box", "--eps", "1:b:2",
                                  data=data)
    # A float option's refusal says what is wrong: NaN is not a number (a bare range
    # check read it as above the maximum: "less than or equal to 1"), inf not finite.
    for option, value, why in (("--eps", "nan", "'nan' is not a number"),
                               ("--eps", "inf", "'inf' is not a finite number"),
                               ("--eps", "2", "'2' is not in [1e-09, 1]"),
                               ("--budget-ms", "nan", "'nan' is not a number")):
        assert f"Invalid value for '{option}': {why}" in cli_error(
            capsys, "render", "-s", "cornell-box", option, value, data=data)
    help_text = cli("sweep", "--help")
    assert "a:b:step" in help_text and "\N{NEGATIVE SQUARED LATIN CAPITAL LETTER B}" not in help_text


SCENE_XML = """<scene version="3.0.0">
  <default name="spp" value="64"/>
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film>
  </sensor>
  <shape type="rectangle"><bsdf type="diffuse"/></shape>
  <emitter type="constant"/>
</scene>
"""


def test_an_external_scene_lists_the_settings_the_run_replaced(tmp_path):
    scene = tmp_path / "my-room.xml"
    scene.write_text(SCENE_XML)
    data = tmp_path / "data"
    text = cli("render", "-s", str(scene), "--res", "8", "--spp", "1", "--frames", "2",
               "--seeds", "2", "--ref-spp", "16", data=data)
    replaced = ["film 32x24 -> 8x8 (the run's resolution)", "integrator 'path' -> pt's own",
                "max_depth 3 -> -1 (the run's)", "sampler 64 spp -> 1 spp x 2 frames"]
    for line in replaced:
        assert line in text
    stored = json.loads(cli("runs", "show", "1", "--json", data=data))
    assert stored["scene_overrides"] == replaced and "scene_overrides" not in stored["params"]


def test_run_and_sweep_tables_state_eps_and_mark_loaded_times(store_dir):
    """The run table names the eps of its relative errors (the run's own: 0.05 here); a
    sweep row timed on a loaded machine reads 'L' after its ms/frame, explained under
    the table, a quiet one reads its time alone. Planted: with the flags dropped no
    row is marked and no line explains."""
    from rich.console import Console

    from jobs.protocol.results import RunResultDetail
    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.sweeps.sweep import SweepResult, point_row
    from service.tables import metrics_table, sweep_table

    data, _ = store_dir
    run = open_store(Settings(data_dir=data)).get_run(1)

    def shown(table) -> str:
        console = Console(width=300, record=True)
        console.print(table)
        return console.export_text()

    detail = RunResultDetail.of(run)
    detail = detail.model_copy(update={"metrics": {**detail.metrics, "eps": 0.05}})
    eps_row = next(line for line in shown(metrics_table(detail)).splitlines()
                   if "eps of the relative errors" in line)
    assert "0.05" in eps_row
    loaded = ["loaded: other work held the CPU"]
    work = dict.fromkeys(("reference_rendered", "snapshots_trained", "snapshots_reused",
                          "points_rendered", "points_reused", "calibrations"), 0)

    def sweep(flags: list[list[str]]) -> str:
        rows = [point_row("nirc", eps, run).model_copy(update={
            "timing_flags": flag, "seconds_per_frame": 0.002 * (k + 1), "render_key": str(k)})
            for k, (eps, flag) in enumerate(zip((0.1, 0.5), flags, strict=True))]
        return shown(sweep_table(SweepResult(sweep_id=1, key="k", kind="eps",
                                             scene="cornell-box", device_key=run.device_key,
                                             rows=rows, skipped=[], work=work)))

    text = sweep(flags=[[], loaded])
    cells = [[cell.strip() for cell in line.split("│")] for line in text.splitlines()
             if line.startswith("│")]
    ms_column = next(line for line in text.splitlines() if "series" in line).split("┃")
    ms_index = [cell.strip() for cell in ms_column].index("ms/frame")
    assert [row[ms_index] for row in cells] == ["2", "4 L"]
    assert "L after ms/frame: timed on a loaded machine" in text
    planted = sweep(flags=[[], []])
    assert " L" not in planted and "loaded machine" not in planted


def test_a_parameter_sweep_table_shows_its_value_not_eps_or_n_c(store_dir):
    """A parameter sweep's rows are its values: the table heads the value column with
    the parameter and shows no eps or N_c at v1 column (both read '-' in every row)."""
    from rich.console import Console

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from jobs.sweeps.sweep import SweepResult, point_row
    from service.tables import sweep_table

    data, _ = store_dir
    run = open_store(Settings(data_dir=data)).get_run(1)
    work = dict.fromkeys(("reference_rendered", "snapshots_trained", "snapshots_reused",
                          "points_rendered", "points_reused", "calibrations"), 0)
    rows = [point_row("nirc", None, run).model_copy(update={"value": value, "nc": None})
            for value in (0.01, 0.1)]

    def header(kind: str, parameter: str | None) -> list[str]:
        console = Console(width=300, record=True)
        console.print(sweep_table(SweepResult(sweep_id=1, key="k", kind=kind, parameter=parameter,
                                              scene="cornell-box", device_key=run.device_key,
                                              rows=rows, skipped=[], work=work)))
        line = next(line for line in console.export_text().splitlines() if "series" in line)
        return [cell.strip() for cell in line.split("┃") if cell.strip()]

    swept = header("parameter", "sph_c")
    assert swept[:2] == ["series", "sph_c"] and "eps" not in swept and "N_c v1" not in swept
    assert header("eps", None)[:3] == ["series", "eps", "N_c v1"]


def test_the_report_prints_without_a_calibration_left_out_on_a_loaded_machine():
    """A report whose N_c calibration was left out (every probe timed on a loaded
    machine) prints its rows and the reason; it stopped with 'internal error
    (KeyError): 'fits'' after the renders."""
    from rich.console import Console

    from jobs.pareto.report import Report, Skipped
    from service.tables import comparison_tables

    left_out = Skipped(method="nirc", label="NIRC (equal time)",
                       reason="every calibration probe was timed on a loaded machine")
    console = Console(width=300, record=True)
    console.print(comparison_tables(Report(scene="cornell-box", device="cpu",
                                           left_out=[left_out])))
    text = console.export_text()
    assert "left out NIRC (equal time): every calibration probe" in text
    assert "N_c calibration" not in text
