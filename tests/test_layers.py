"""The layer rules of the code base, checked on every import statement, the ones
inside functions included: ``service -> jobs -> renderers, metrics``; inside
``jobs`` the record, the core of a job (``jobs.protocol``), the views of stored runs
and the cost model (``jobs.views``, ``jobs.costs``: :data:`SHARED`), the studies built
on them and execution each import only the layers below them; a shared package imports
only the core and the record; a study never imports another study (but for the edges
:data:`STUDY_EDGES` names); and no two sub-packages import each other, directly or
through others.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("service", "jobs", "renderers", "metrics")
#: What each top-level package may import of the others.
ALLOWED = {"service": {"jobs", "renderers", "metrics"}, "jobs": {"renderers", "metrics"},
           "renderers": {"metrics"}, "metrics": set()}
#: Built on the core alone and shared by the studies, execution and the service: the views
#: of stored runs (charts, figures, fronts, comparisons, queries, exports) and the cost model.
SHARED = ("views", "costs")
#: The studies: each builds on the core of a job and is run by execution or the service.
STUDIES = ("sweeps", "pareto", "ci", "stress")
#: Above the studies: execution runs them; reproduce composes their runs into papers' figures.
JOBS_LAYERS = {"record": 0, "protocol": 1, **dict.fromkeys(SHARED, 2),
               **dict.fromkeys(STUDIES, 3), "execution": 4, "reproduce": 4}
#: (study, study) imports allowed: none (every study needs only the core).
STUDY_EDGES: set[tuple[str, str]] = set()
#: Sub-package circles allowed: none (the oracle caches, which import the path-tracing
#: core, live in the test-support package tests/support).
KNOWN_CIRCLES: set[tuple[str, str]] = set()


def _imports() -> dict[str, set[str]]:
    """module -> the project modules it imports anywhere in its source."""
    edges: dict[str, set[str]] = defaultdict(set)
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            module = module.removesuffix(".__init__")
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                elif isinstance(node, ast.ImportFrom):   # relative: resolve against the module
                    base = module.split(".")[:len(module.split(".")) - node.level +
                                              (path.name == "__init__.py")]
                    names = [".".join(base + ([node.module] if node.module else []))]
                else:
                    continue
                edges[module] |= {name for name in names if name.split(".")[0] in PACKAGES}
    return edges


EDGES = _imports()


def test_the_scan_sees_function_level_imports():
    """The scan is not blind to imports inside functions (the cache's build does one)."""
    assert "renderers.caches.config" in EDGES["renderers.methods.nirc"]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_runs_up_a_layer(package):
    wrong = sorted((module, name) for module, names in EDGES.items()
                   if module.split(".")[0] == package for name in names
                   if name.split(".")[0] not in ALLOWED[package] | {package})
    assert wrong == []


def _jobs_package(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "jobs" else None


def _upward(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The imports in ``edges`` of a jobs module from a jobs layer above its own."""
    def layer(module: str) -> int:
        return JOBS_LAYERS.get(_jobs_package(module) or "", -1)

    return sorted((module, name) for module, names in edges.items()
                  if _jobs_package(module) for name in names
                  if _jobs_package(name) and layer(name) > layer(module))


def _shared_beyond_the_core(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The imports in ``edges`` of a shared package from jobs packages other than
    itself, the core and the record (another shared package included)."""
    return sorted((module, name) for module, names in edges.items()
                  if _jobs_package(module) in SHARED for name in names
                  if _jobs_package(name) not in {None, _jobs_package(module), "protocol",
                                                 "record"})


def test_the_jobs_layers_import_only_those_below():
    assert _upward(EDGES) == []


def test_a_shared_package_imports_only_the_core_and_the_record():
    assert _shared_beyond_the_core(EDGES) == []


def test_the_layer_checks_refuse_planted_imports():
    """Each check fails on the import it exists to refuse, planted beside the real ones."""
    planted = {"jobs.protocol.executor": {"jobs.views.export"},    # the core, one layer up
               "jobs.views.charts": {"jobs.pareto.pareto"},         # a view on a study
               "jobs.record.store": {"jobs.protocol.spec"}}         # the record on the core
    assert _upward({**EDGES, **planted}) == sorted(
        (module, name) for module, names in planted.items() for name in names)
    sideways = {"jobs.views.plots": {"jobs.costs.cost_model"},
                "jobs.costs.cost_model": {"jobs.execution.work"}}
    assert _shared_beyond_the_core({**EDGES, **sideways}) == sorted(
        (module, name) for module, names in sideways.items() for name in names)


def test_every_jobs_package_has_a_layer():
    """A new package under jobs/ is placed in the layers before it is used."""
    packages = {path.parent.name for path in (ROOT / "jobs").glob("*/__init__.py")}
    assert packages == set(JOBS_LAYERS)


def test_a_study_imports_the_core_and_no_other_study():
    def study(module: str) -> str | None:
        parts = module.split(".")
        return parts[1] if len(parts) > 1 and parts[0] == "jobs" and parts[1] in STUDIES else None

    edges = {(study(module), study(name)) for module, names in EDGES.items() if study(module)
             for name in names if study(name) and study(name) != study(module)}
    assert edges <= STUDY_EDGES, sorted(edges - STUDY_EDGES)


def test_the_core_imports_no_study():
    wrong = sorted((module, name) for module, names in EDGES.items()
                   if module.startswith("jobs.protocol") for name in names
                   if name.split(".")[1:2] and name.split(".")[0] == "jobs"
                   and name.split(".")[1] in STUDIES)
    assert wrong == []


def test_no_circle_between_sub_packages():
    def sub_package(module: str) -> str:
        return ".".join(module.split(".")[:2])

    graph: dict[str, set[str]] = defaultdict(set)
    for module, names in EDGES.items():
        for name in names:
            if sub_package(module) != sub_package(name):
                graph[sub_package(module)].add(sub_package(name))

    def reachable(start: str) -> set[str]:
        seen, stack = set(), [start]
        while stack:
            for nxt in graph.get(stack.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        return seen

    circles = {tuple(sorted((a, b))) for a in list(graph) for b in graph[a] if a in reachable(b)}
    assert circles == KNOWN_CIRCLES
