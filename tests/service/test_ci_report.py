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


def test_the_summary_and_junit_name_the_regression_and_only_it():
    result = _planted_result()
    rows = len(result.rows)
    assert rows == 6 + 4 and headline(result) == f"REGRESSION: 1 of {rows} rows"
    text = markdown(result)
    assert text.startswith(f"## nirc-bench ci: REGRESSION: 1 of {rows} rows\n")
    table = [line for line in text.splitlines() if line.startswith("| ")][1:]   # no header
    verdicts = [(line.split(" | ")[0:2], line.rsplit(" | ", 1)[1]) for line in table]
    assert verdicts.count((["| nirc biased", "MRSE (lower is better)"], "**REGRESSION** |")) == 1
    assert sum(verdict == "pass |" for _row, verdict in verdicts) == 6 - 1, text   # compared

    suite = ET.fromstring(junit(result)).find("testsuite")
    assert (suite.get("tests"), suite.get("failures")) == (str(rows), "1")
    failed = [(case.get("classname"), case.get("name")) for case in suite.iter("testcase")
              if case.find("failure") is not None]
    assert failed == [("nirc biased", "mrse")]
