"""The outputs of ``nirc-bench ci``: a Markdown summary (a pull-request comment) and JUnit XML."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from jobs.ci.ci import CiResult, CiRow

_VERDICT = {"pass": "pass", "regression": "**REGRESSION**", "not comparable": "not comparable",
            "shown": "shown (not gated)"}


def _number(value: float | None) -> str:
    return "–" if value is None else f"{value:.4g}"


def _change(row: CiRow) -> str:
    """The relative change the way a reader expects: + is worse."""
    return "–" if row.change is None else f"{row.change:+.1%} (worse)" if row.change > 0 \
        else f"{row.change:+.1%}"


def _candidate(row: CiRow) -> str:
    """The candidate's value with its 95 % interval where it has one."""
    ci = row.candidate_ci95
    return _number(row.candidate) + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci else "")


def _p(value: float | None) -> str:
    return "–" if value is None else f"{value:.2g}"


def headline(result: CiResult) -> str:
    """'PASS: 5 rows compared' or 'REGRESSION: 1 of 5 rows compared', then the rows not
    gated; the count of compared rows is JUnit's tests less its skipped."""
    counts = result.counts
    rest = "".join(f", {n} {what}" for n, what in ((counts.not_comparable, "not comparable"),
                                                   (counts.shown, "shown (not gated)")) if n)
    if counts.regressions:
        return f"REGRESSION: {counts.regressions} of {counts.compared} rows compared{rest}"
    return f"PASS: {counts.compared} rows compared{rest}"


def markdown(result: CiResult) -> str:
    """The summary table: baseline, candidate, change, p-value, seeds and verdict per row."""
    branch = f" ({result.branch})" if result.branch else ""
    lines = [
        f"## nirc-bench ci: {headline(result)}", "",
        f"Suite `{result.suite}` against `{result.baseline}` at commit `{result.commit[:12]}`"
        f"{branch}. A row is a regression when a one-sided test shows it worse by at least "
        f"its minimum change (the lower confidence bound of the change above it, not the "
        f"estimate): false-failure level {result.level:g} for the whole suite (Bonferroni over "
        f"the rows, {result.spending} alpha spending over the looks); p is that test's.", "",
        "| configuration | metric | baseline | candidate [95% CI] | change | min. change | p-value "
        "| seeds (baseline) | test | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in result.rows:
        lines.append(
            f"| {row.entry} | {row.metric_label} ({row.direction} is better) "
            f"| {_number(row.baseline)} | {_candidate(row)} | {_change(row)} "
            f"| {row.min_change:.0%} | {_p(row.p_value)} | {row.seeds} ({row.baseline_seeds}) "
            f"| {row.test or '–'} | {_VERDICT[row.verdict]} |")
    notes = [f"- {row.entry}, {row.metric_label}: {row.note}" for row in result.rows
             if row.verdict != "pass" or row.metric in ("rbias2", "rvar")]
    if notes:
        lines += ["", *notes]
    lines += ["", f"{len(result.runs)} runs stored ({result.seconds:.0f} s)."]
    return "\n".join(lines) + "\n"


def junit(result: CiResult) -> str:
    """JUnit XML: a test case per row; a regression fails, a row not compared or shown
    without a gate is skipped (so the cases run are the headline's compared rows)."""
    counts = result.counts
    suite = ET.Element("testsuite", name="nirc-bench ci", tests=str(len(result.rows)),
                       failures=str(counts.regressions), errors="0",
                       skipped=str(counts.not_comparable + counts.shown),
                       time=f"{result.seconds:.3f}")
    for row in result.rows:
        case = ET.SubElement(suite, "testcase", classname=row.entry, name=row.metric)
        detail = (f"baseline {_number(row.baseline)}, candidate {_candidate(row)}, "
                  f"change {_change(row)}, p {_p(row.p_value)}, {row.seeds} seeds; {row.note}")
        if row.verdict == "regression":
            ET.SubElement(case, "failure", message=row.note).text = detail
        elif row.verdict in ("not comparable", "shown"):
            ET.SubElement(case, "skipped", message=f"{_VERDICT[row.verdict]}: {row.note}"
                          ).text = detail
        else:
            ET.SubElement(case, "system-out").text = detail
    root = ET.Element("testsuites")
    root.append(suite)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode")
