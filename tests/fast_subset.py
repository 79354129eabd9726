"""``make test-fast`` (``--fast-subset``): a fixed subset of the suite, marked ``fast``,
that exercises every module of the product.

The subset is the list of node ids in ``tests/fast_tests.txt`` (ini ``fast_tests``; one id
a line, ``#`` starts a comment; an id without its ``[parameters]`` takes every
parametrisation). Collection always marks the listed tests ``fast`` (``-m fast`` selects
them in any run).

``--fast-subset`` runs the list: the test files it does not name are not even imported,
the tests it does not name are deselected, and an id that names no collected test is an
error. The run measures, with coverage.py's line data recorded from the first test's
setup to the last test's teardown (so imports at collection do not count), which modules
of the product packages (ini ``product_packages``: renderers, metrics, jobs, service) it
exercised: a module is exercised when a line of one of its function bodies ran, in the
test process or in a Python process a test started (a CLI test's ``nirc-bench``, a
render process: coverage.py's start-up hook measures them through
``COVERAGE_PROCESS_CONFIG``, each writing its lines to a spool folder read at the end).
A module
that defines no function (a package's ``__init__``, a declarative subclass) has nothing to
run but its body: it counts when it was imported or run. The summary says ``fast subset:
N tests; product modules exercised: M of T`` and names every module missed; a missed
module fails the run.
"""

from __future__ import annotations

import ast
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import coverage
import pytest

LIST = Path(__file__).with_name("fast_tests.txt")
PRODUCT_PACKAGES = ["renderers", "metrics", "jobs", "service"]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--fast-subset", action="store_true", default=False,
                     help="run only the tests listed in tests/fast_tests.txt and fail naming "
                          "each product module they do not exercise (tests/fast_subset.py)")
    parser.addini("product_packages", type="linelist", default=PRODUCT_PACKAGES,
                  help="folders (relative to the rootdir) whose modules --fast-subset checks")
    parser.addini("fast_tests", type="string", default=str(LIST),
                  help="the file listing the node ids marked fast")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "fast: listed in tests/fast_tests.txt, the subset of "
                                       "make test-fast (tests/fast_subset.py)")
    config.pluginmanager.register(FastSubset(config), "nirc-bench-fast-subset")


def listed_ids(path: Path) -> set[str]:
    """The node ids of the list file, without comments and blank lines."""
    lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
    return {line for line in lines if line}


def function_lines(path: Path) -> set[int] | None:
    """The lines of ``path``'s function bodies (``def`` only: a lambda shares its line
    with the code around it); None for a module that defines no function."""
    tree = ast.parse(path.read_text(), str(path))
    functions = [node for node in ast.walk(tree)
                 if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))]
    if not functions:
        return None
    return {line for node in functions
            for line in range(node.body[0].lineno, node.end_lineno + 1)}


class FastSubset:
    """Marks the listed tests ``fast``; under ``--fast-subset`` runs them alone and checks
    that they exercise every product module."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.root = Path(config.rootpath)
        self.path = self.root / config.getini("fast_tests")
        self.listed = listed_ids(self.path) if self.path.is_file() else set()
        self.files = {nodeid.split("::", 1)[0] for nodeid in self.listed}
        self.subset = config.getoption("fast_subset")
        self.coverage: coverage.Coverage | None = None
        self.spool: Path | None = None
        self.selected = 0
        self.modules: list[Path] = []
        self.missed: list[str] = []
        self.declarative = 0

    def pytest_ignore_collect(self, collection_path: Path) -> bool | None:
        if (self.subset and collection_path.suffix == ".py"
                and collection_path.name != "conftest.py"
                and collection_path.relative_to(self.root).as_posix() not in self.files):
            return True
        return None

    @pytest.hookimpl(tryfirst=True)      # before -m deselects
    def pytest_collection_modifyitems(self, config: pytest.Config, items: list[Any]) -> None:
        matched: set[str] = set()
        for item in items:
            for nodeid in (item.nodeid, item.nodeid.split("[", 1)[0]):
                if nodeid in self.listed:
                    item.add_marker(pytest.mark.fast)
                    matched.add(nodeid)
        if not self.subset:
            return
        stale = sorted(self.listed - matched)
        if stale:
            raise pytest.UsageError(
                f"{self.path.name} names tests that were not collected (renamed or removed?): "
                + ", ".join(stale))
        unlisted = [item for item in items if item.get_closest_marker("fast") is None]
        if unlisted:
            config.hook.pytest_deselected(items=unlisted)
            items[:] = [item for item in items if item.get_closest_marker("fast") is not None]

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtestloop(self, session: pytest.Session) -> Iterator[None]:
        if self.subset and not session.config.option.collectonly:
            self.selected = len(session.items)
            include = [str(self.root / package / "*")
                       for package in self.config.getini("product_packages")]
            self.coverage = coverage.Coverage(data_file=None, config_file=False,
                                              include=include)
            self.spool = Path(tempfile.mkdtemp(prefix="nirc-bench-fast-subset-"))
            started = coverage.Coverage(data_file=str(self.spool / "process"),
                                        config_file=False, include=include)
            started.set_option("run:parallel", True)     # one data file per process
            started.set_option("run:sigterm", True)      # a live service stopped by SIGTERM
            os.environ["COVERAGE_PROCESS_CONFIG"] = started.config.serialize()
            self.coverage.start()
        try:
            yield
        finally:
            if self.coverage is not None:
                self.coverage.stop()
                os.environ.pop("COVERAGE_PROCESS_CONFIG", None)

    def lines_run(self) -> dict[str, set[int]]:
        """The lines run per file, in this process and in the processes tests started."""
        assert self.coverage is not None and self.spool is not None
        measured = [self.coverage.get_data()]
        for data_file in self.spool.glob("process*"):
            measured.append(coverage.CoverageData(basename=str(data_file)))
            measured[-1].read()
        ran: dict[str, set[int]] = {}
        for data in measured:
            for path in data.measured_files():
                ran.setdefault(path, set()).update(data.lines(path) or ())
        return ran

    @pytest.hookimpl(tryfirst=True)
    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        if self.coverage is None:
            return
        ran_per_file = self.lines_run()
        imported = {getattr(module, "__file__", None) for module in list(sys.modules.values())}
        for package in self.config.getini("product_packages"):
            for path in sorted((self.root / package).rglob("*.py")):
                self.modules.append(path)
                ran = ran_per_file.get(str(path), set())
                body = function_lines(path)
                if body is None:
                    self.declarative += 1
                    exercised = bool(ran) or str(path) in imported
                else:
                    exercised = bool(body & ran)
                if not exercised:
                    self.missed.append(".".join(path.relative_to(self.root)
                                                .with_suffix("").parts))
        shutil.rmtree(self.spool, ignore_errors=True)
        if self.missed and session.exitstatus == pytest.ExitCode.OK:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        if self.coverage is None:
            return
        terminalreporter.write_line(
            f"fast subset: {self.selected} tests; product modules exercised: "
            f"{len(self.modules) - len(self.missed)} of {len(self.modules)} (a line of a "
            f"function body ran in a test; the {self.declarative} without a function count "
            f"when imported)")
        if self.missed:
            terminalreporter.write_line(
                f"FAILED: no test of the fast subset exercised these {len(self.missed)} "
                f"product modules (list a test that does in {self.path.name}): "
                + ", ".join(self.missed), red=True, bold=True)
