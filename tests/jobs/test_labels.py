"""Runs are labelled by what defines them (jobs/protocol/labels.py), and the history
over commits never pools runs of two labels."""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace

from jobs.ci.history import build_history
from jobs.protocol.labels import changed_params, resolved_params, run_label
from jobs.protocol.results import method_params
from metrics.registry import METRICS

MRSE = next(m for m in METRICS if m.name == "mrse")


def _sweep_point(eps: float, nc: list[int], **sweep) -> dict:
    """A stored NIRC sweep point's parameters (as the sweep stores them)."""
    return {"estimator": "biased", "termination": "adaptive", "nc": nc, "max_depth": -1,
            "sweep": {"series": "nirc", "eps": eps, "mask_fraction": 1.0, **sweep}}


def test_sweep_points_are_labelled_by_eps_and_n_c():
    labels = {run_label("nirc", _sweep_point(eps, nc))
              for eps, nc in ((0.6, [1, 1]), (0.8, [1, 1]), (0.8, [2, 1]), (0.8, [4, 1]))}
    assert labels == {"nirc (adaptive, N_c 1,1, eps 0.6)", "nirc (adaptive, N_c 1,1, eps 0.8)",
                      "nirc (adaptive, N_c 2,1, eps 0.8)", "nirc (adaptive, N_c 4,1, eps 0.8)"}
    # What a point stores besides (its mask coverage, its caches) does not define it.
    assert run_label("nirc", _sweep_point(0.6, [1, 1], mask_fraction=0.5, snapshots=["a"])) \
        == "nirc (adaptive, N_c 1,1, eps 0.6)"


def test_labels_show_resolved_values_that_differ_from_the_defaults():
    # nc = None stands for the policy's default N_c: resolved, not shown as 'None'.
    assert resolved_params("nirc", {"nc": None})["nc"] == [4]
    assert resolved_params("nirc", {"nc": None, "estimator": "unbiased"})["nc"] == [3, 1, 1]
    assert run_label("nirc", {"nc": None}) == run_label("nirc", {"nc": [4]}) == "nirc"
    assert run_label("nirc", {"estimator": "unbiased", "nc": None}) == "nirc (unbiased, N_c 3,1,1)"
    assert run_label("pt", {"max_depth": 4, "rr_mode": "throughput", "rr_survival": 0.9}) \
        == "pt (max_depth 4, rr_mode throughput)"
    assert run_label("grid-cache", {"termination": "var-bound",
                                    "termination_params": {"threshold": 0.5}}) \
        == "grid-cache (termination_params {threshold:0.5})"
    assert changed_params("pt", {"max_depth": -1}) == {}
    # Parameters today's model refuses (stored by older code) are shown as stored.
    assert resolved_params("nirc", {"rr_survival": 2.0, "nc": None})["nc"] is None


def test_the_readme_names_runs_as_tables_do():
    """The README's example of a table's title is the label of its parameters, and its
    NIRC at the defaults reads as the tables print it (it read 'nirc (biased, bth, N_c
    4)' while tables printed 'nirc')."""
    text = " ".join((Path(__file__).parents[2] / "README.md").read_text().split())
    passage = text[text.index('"scene / method" row read e.g.'):]
    example, at_defaults = re.findall(r"`([^`]+)`", passage)[:2]
    assert example == run_label("nirc", {"termination": "sph", "nc": [8]})
    assert at_defaults == run_label("nirc", {"estimator": "biased", "termination": "bth",
                                             "nc": [4]})


def _run(run_id: int, params: dict, commit: str, value: float) -> SimpleNamespace:
    return SimpleNamespace(
        id=run_id, method="nirc", params=params, width=8, height=8, spp=1, frames=1,
        git_commit=commit, git_branch="main", metric_version=1, estimator_version=1,
        scene_fingerprint="f", device_key="d", created_at=datetime(2026, 1, run_id, tzinfo=UTC),
        quality={}, metrics={"mrse": value}, seed_results=[
            SimpleNamespace(metrics={"mrse_seed": value + d}) for d in (0.0, 0.01)])


def test_history_never_pools_runs_with_different_labels():
    """Two eps of one commit are two series (each its own median), labelled apart; two
    runs of one label whose stored extras differ are one series."""
    runs = [_run(1, _sweep_point(0.6, [1, 1]), "a" * 40, 0.1),
            _run(2, _sweep_point(0.8, [1, 1]), "a" * 40, 0.5),
            _run(3, _sweep_point(0.6, [1, 1], snapshots=["other"]), "b" * 40, 0.1),
            _run(4, _sweep_point(0.8, [1, 1], snapshots=["other"]), "b" * 40, 0.5)]
    for run in runs:     # the metric's per-seed key
        for seed in run.seed_results:
            seed.metrics = {MRSE.seed_key: seed.metrics["mrse_seed"]}
    history = build_history(runs, MRSE, scene="s", method="nirc")
    by_label = {series.label: series for series in history.series}
    assert set(by_label) == {"nirc (adaptive, N_c 1,1, eps 0.6)",
                             "nirc (adaptive, N_c 1,1, eps 0.8)"}
    for label, median in (("nirc (adaptive, N_c 1,1, eps 0.6)", 0.105),
                          ("nirc (adaptive, N_c 1,1, eps 0.8)", 0.505)):
        points = by_label[label].points
        assert [p.commit[0] for p in points] == ["a", "b"]
        assert all(abs(p.median - median) < 1e-12 and p.n == 2 for p in points)
    # Planted: grouped by the stored parameters, the four runs are four series of one
    # commit each (nothing to compare), two of them under each label.
    stored = {json.dumps(method_params(run.params), sort_keys=True) for run in runs}
    assert len(stored) == 4
