"""The CI gate's summary and JUnit report (service/ci_report.py) of a result with a
planted regression (the comparison itself: tests/jobs/test_ci.py)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from service.ci_report import headline, junit, markdown
from tests.jobs.ci_fakes import FakeRunner
from tests.jobs.test_ci import MEANS, baseline_of, normal_draw, run, small_suite


def _planted_result():
    suite = small_suite()
    worse = normal_draw(MEANS, 0.1, seed=5,
                        scale=lambda label, m: 2.0 if (label, m) == ("nirc biased", "mrse") else 1)
    return run(suite, FakeRunner(suite, worse),
               baseline_of(suite, normal_draw(MEANS, 0.1, seed=4), range(16)), seed_start=100)


def _verdicts(result) -> list[str]:
    """The verdict of every row, read off the summary table."""
    return [line.removesuffix(" |").rsplit(" | ", 1)[1]
            for line in markdown(result).splitlines() if line.startswith("| ")][1:]


def _compared(result) -> int:
    """The rows gated: pass or regression."""
    return sum(verdict in ("pass", "**REGRESSION**") for verdict in _verdicts(result))


def test_the_summary_and_junit_name_the_regression_and_only_it():
    result = _planted_result()
    rows = len(result.rows)
    # 6 compared rows; each of the 2 entries adds its rBias² and rVar rows (gated for pt,
    # which claims to be unbiased, when comparable; shown for nirc).
    verdicts = _verdicts(result)
    assert rows == 6 + 4 == len(verdicts)
    compared = _compared(result)
    assert headline(result) == (
        f"REGRESSION: 1 of {compared} rows compared, "
        f"{verdicts.count('not comparable')} not comparable, "
        f"{verdicts.count('shown (not gated)')} shown (not gated)")
    text = markdown(result)
    assert text.startswith(f"## nirc-bench ci: {headline(result)}\n")
    table = [line for line in text.splitlines() if line.startswith("| ")][1:]   # no header
    verdicts = [(line.split(" | ")[0:2], line.rsplit(" | ", 1)[1]) for line in table]
    assert verdicts.count((["| nirc biased", "MRSE (lower is better)"], "**REGRESSION** |")) == 1
    assert sum(verdict == "pass |" for _row, verdict in verdicts) == 6 - 1, text   # compared

    suite = ET.fromstring(junit(result)).find("testsuite")
    assert (suite.get("tests"), suite.get("failures")) == (str(rows), "1")
    assert int(suite.get("tests")) - int(suite.get("skipped")) == compared
    failed = [(case.get("classname"), case.get("name")) for case in suite.iter("testcase")
              if case.find("failure") is not None]
    assert failed == [("nirc biased", "mrse")]


def test_one_count_of_compared_rows_in_the_headline_summary_and_junit():
    """Passing and failing, the headline's rows compared are the summary's gated rows and
    JUnit's cases run (tests less skipped); a failing gate counts its regressions among
    them. Planted: a count over every row (shown ones too) disagrees with JUnit's."""
    suite = small_suite()
    passed = run(suite, FakeRunner(suite, normal_draw(MEANS, 0.1, seed=5)),
                 baseline_of(suite, normal_draw(MEANS, 0.1, seed=4), range(16)), seed_start=100)
    for result, word in ((passed, "PASS"), (_planted_result(), "REGRESSION")):
        cases = ET.fromstring(junit(result)).find("testsuite")
        run_cases = int(cases.get("tests")) - int(cases.get("skipped"))
        assert run_cases == _compared(result) == result.counts.compared
        assert headline(result).startswith(word)
        told = int(headline(result).split(" rows compared")[0].split()[-1])
        assert told == run_cases
        assert len(result.rows) != run_cases                   # the planted count
