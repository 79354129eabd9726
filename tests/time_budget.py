"""``--time-budget SECONDS`` (``make test-fast``): run the tests whose measured times fit.

Every run records each test's time (setup + call + teardown) on this machine in pytest's
cache (``.pytest_cache``). With ``--time-budget S``, the selected tests are ordered by
their recorded time and the cheapest are kept while their sum stays within S; tests
never timed here (new ones, or all of them in a fresh checkout) are kept too, since
their cost is unknown, and run first. Whatever the record, the run stops starting tests once S seconds
have passed (the test under way finishes; the rest are not started and counted in the summary), so a
fresh checkout also stays within the budget and records what it ran. The summary says what was left out, what was not
reached, and how long it took when last run: ``make test`` runs everything and
refreshes the record.
"""

from __future__ import annotations

import time
from typing import Any

import pytest

CACHE_KEY = "nirc-bench/test-seconds"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--time-budget", type=float, default=None, metavar="SECONDS",
                     help="run only the cheapest tests whose recorded times sum to at most "
                          "SECONDS (tests/time_budget.py)")


def pytest_configure(config: pytest.Config) -> None:
    config.pluginmanager.register(TimeBudget(config), "nirc-bench-time-budget")


class TimeBudget:
    """Records test times; selects by them under ``--time-budget``."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        # pytest's cache (where times are kept) is absent under `-p no:cacheprovider`.
        self.cache = getattr(config, "cache", None)
        self.recorded: dict[str, float] = self.cache.get(CACHE_KEY, {}) if self.cache else {}
        self.measured: dict[str, float] = {}
        self.kept_s = 0.0
        self.left_out: list[Any] = []
        self.untimed = 0
        self.ran: set[str] = set()     # tests whose body ran: only their times are kept
        self.started = time.monotonic()
        self.stopped_after: int | None = None     # tests run when the budget ran out
        self.not_started = 0

    def pytest_collection_modifyitems(self, config: pytest.Config, items: list[Any]) -> None:
        budget = config.getoption("time_budget")
        if budget is None:
            return
        timed = sorted((item for item in items if item.nodeid in self.recorded),
                       key=lambda item: self.recorded[item.nodeid])
        self.untimed = len(items) - len(timed)
        keep = {item.nodeid for item in items if item.nodeid not in self.recorded}
        for item in timed:
            seconds = self.recorded[item.nodeid]
            if self.kept_s + seconds > budget:
                self.left_out.append(item)
                continue
            self.kept_s += seconds
            keep.add(item.nodeid)
        if self.left_out:
            config.hook.pytest_deselected(items=self.left_out)
        # Untimed tests first: a budget spent on them still records new times, so
        # successive runs time the whole suite; then the timed ones, in file order.
        items[:] = ([item for item in items if item.nodeid not in self.recorded]
                    + [item for item in items
                       if item.nodeid in self.recorded and item.nodeid in keep])

    def pytest_runtestloop(self, session: pytest.Session) -> None:
        self.started = time.monotonic()

    @pytest.hookimpl(tryfirst=True)
    def pytest_runtest_protocol(self, item: Any, nextitem: Any) -> bool | None:
        """Once the budget is spent, the remaining tests are not started at all (not run,
        not reported): returning True tells pytest this item is dealt with."""
        budget = self.config.getoption("time_budget")
        if budget is None or time.monotonic() - self.started <= budget:
            return None
        if self.stopped_after is None:
            self.stopped_after = len(self.ran)
        self.not_started += 1
        return True

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.measured[report.nodeid] = self.measured.get(report.nodeid, 0.0) + report.duration
        if report.when == "call":
            self.ran.add(report.nodeid)

    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        timed = {nodeid: s for nodeid, s in self.measured.items() if nodeid in self.ran}
        if self.cache is not None and timed:
            self.cache.set(CACHE_KEY, {**self.recorded, **timed})

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        if self.config.getoption("time_budget") is None:
            return
        left_s = sum(self.recorded[item.nodeid] for item in self.left_out)
        terminalreporter.write_line(
            f"time budget: kept tests recorded at {self.kept_s:.1f} s; left out "
            f"{len(self.left_out)} tests recorded at {left_s:.1f} s (make test runs them); "
            f"{self.untimed} tests had no recorded time")
        if self.stopped_after is not None:
            terminalreporter.write_line(
                f"time budget: spent after {self.stopped_after} tests; the other "
                f"{self.not_started} were not started")
