"""``nirc-bench ci`` end to end with real renders: its own baseline passes, an edited one
fails on the edited rows, other versions are not compared, bad input exits 2; embedded,
against the database's results of a branch, and over REST."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path

import pytest

from tests.service.live import Service
from tests.service.test_cli import assert_clean_error, run_cli, started_together

# Small and quick: 16x16 pixels, 4 frames, seeds in groups of 3 up to 6, level 0.01. No
# time row: the tests share a loaded machine (time is tested with fake runs in
# tests/jobs/test_ci.py).
SUITE = """
scenes = ["cornell-box"]
resolution = 16
frames = 4
ref_spp = 256
metrics = ["mrse", "psnr"]
level = 0.01
group = 3
max_seeds = 6

[[methods]]
label = "pt"
method = "pt"
"""
NIRC = """
[[methods]]
label = "nirc biased"
method = "nirc"
params = { estimator = "biased", max_depth = 3 }
"""


@pytest.fixture
def suite(tmp_path: Path) -> Path:
    """PT only (2 rows): the cheap suite of the tests that check the plumbing."""
    path = tmp_path / "suite.toml"
    path.write_text(SUITE)
    return path


@pytest.fixture
def suite_with_nirc(tmp_path: Path) -> Path:
    """PT and biased NIRC (4 rows)."""
    path = tmp_path / "suite_nirc.toml"
    path.write_text(SUITE + NIRC)
    return path


def ci(suite: Path, baseline: Path, data_dir: Path, *args: str, env=None):
    return run_cli("ci", "--suite", str(suite), "--baseline", str(baseline), *args,
                   data_dir=data_dir, env=env)


def edit(baseline: Path, target: Path, change) -> Path:
    data = json.loads(baseline.read_text())
    for row in data["rows"]:
        change(row)
    target.write_text(json.dumps(data))
    return target


def test_own_baseline_passes_and_a_baseline_edited_to_be_better_fails(tmp_path,
                                                                      suite_with_nirc):
    suite = suite_with_nirc
    data, baseline = tmp_path / "data", tmp_path / "baseline.json"
    written = ci(suite, baseline, data, "--update-baseline")
    assert written.returncode == 0, written.stderr
    rows = json.loads(baseline.read_text())["rows"]
    assert len(rows) == 4 and {len(r["values"]) for r in rows} == {6}

    # The same configuration on the baseline's seeds: paired, decided at the first look.
    own = ci(suite, baseline, data, "--summary", str(tmp_path / "s.md"),
             "--junit", str(tmp_path / "j.xml"))
    assert own.returncode == 0, own.stderr + own.stdout
    # 4 compared rows, and pt's rBias² row: pt claims to be unbiased, so its interval is gated.
    assert "PASS: 5 rows compared" in own.stdout and "| 3 (3) | paired t | pass |" in own.stdout
    cases = ET.parse(tmp_path / "j.xml").getroot().find("testsuite")
    # Each of the 2 entries adds its rBias² and rVar rows to the 4 compared.
    assert cases.get("tests") == "8" and cases.get("failures") == "0"
    assert cases.get("skipped") == "3"                   # the 5 compared rows run
    summary = (tmp_path / "s.md").read_text()
    assert summary.startswith("## nirc-bench ci: PASS") and "| nirc biased | MRSE" in summary

    # The baseline edited to be 3x better on nirc's MRSE, compared on other seeds (unpaired,
    # Welch's t): that row, and only it, fails.
    def better(row):
        if (row["label"], row["metric"]) == ("nirc biased", "mrse"):
            row["values"] = [v / 3 for v in row["values"]]
    edited = edit(baseline, tmp_path / "better.json", better)
    failed = ci(suite, edited, data, "--seed-start", "100", "--junit", str(tmp_path / "j2.xml"))
    assert failed.returncode == 1, failed.stdout + failed.stderr
    cases = ET.parse(tmp_path / "j2.xml").getroot().find("testsuite")
    flagged = {(c.get("classname"), c.get("name")) for c in cases if c.find("failure") is not None}
    assert flagged == {("nirc biased", "mrse")}
    assert "REGRESSION: 1 of 5 rows compared, 3 shown" in failed.stdout
    assert "Welch t" in failed.stdout


def test_the_latest_results_of_a_branch_are_a_baseline(tmp_path, suite):
    data, unused = tmp_path / "data", tmp_path / "none.json"
    first = ci(suite, unused, data, "--baseline-ref", "main", env={"NIRC_BENCH_BRANCH": "main"})
    assert first.returncode == 0 and "no baseline row" in first.stdout
    second = ci(suite, unused, data, "--baseline-ref", "main",
                env={"NIRC_BENCH_BRANCH": "feature"})
    assert second.returncode == 0, second.stdout + second.stderr
    assert "PASS: 3 rows compared" in second.stdout and "paired t" in second.stdout


KEPT_FROM_RUNNING = [
    (("--suite", "nowhere.toml"), "nowhere.toml"),
    (("--baseline", "nowhere.json"), "--update-baseline"),
    (("--server", "http://127.0.0.1:9"), "cannot reach"),
    (("--update-baseline", "--baseline-ref", "main"), "--baseline-ref"),
]


@pytest.fixture(scope="module")
def kept_calls(tmp_path_factory) -> Iterator[dict[tuple[str, ...], Future]]:
    """The calls of the cases below, started together (each a process that spends seconds
    starting before it exits), keyed by their own arguments."""
    folder = tmp_path_factory.mktemp("kept")
    (folder / "suite.toml").write_text(SUITE)
    (folder / "b.json").write_text('{"rows": []}')
    calls = {args: ("ci", "--suite", str(folder / "suite.toml"), "--baseline",
                    str(folder / "b.json"), *args) for args, _ in KEPT_FROM_RUNNING}
    for started in started_together(list(calls.values()), folder):
        yield {args: started[call] for args, call in calls.items()}


@pytest.mark.parametrize("args, fragment", KEPT_FROM_RUNNING)
def test_what_keeps_it_from_running_exits_2(kept_calls, args, fragment):
    proc = kept_calls[args].result()
    assert proc.returncode == 2
    assert_clean_error(proc, fragment)


def test_over_rest(tmp_path, suite):
    service = Service(tmp_path / "service")
    service.start()
    try:
        remote = ("--server", service.url, "--api-key", service.key)
        baseline = tmp_path / "baseline.json"
        written = ci(suite, baseline, tmp_path / "data", *remote, "--update-baseline")
        assert written.returncode == 0, written.stderr
        proc = ci(suite, baseline, tmp_path / "data", *remote)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "PASS: 3 rows compared" in proc.stdout   # and pt's gated rBias² row
        runs = service.get("/api/v1/results")
        assert len(runs) == 2       # one run at the cap, then one group
        detail = service.get(f"/api/v1/runs/{runs[0]['id']}")
        assert detail["git_commit"] and "git_branch" in detail
        assert [s["seed"] for s in detail["per_seed"]] == [0, 1, 2]
    finally:
        service.stop()
