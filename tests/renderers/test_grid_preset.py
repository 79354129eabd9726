"""The grid cache's named presets (renderers/methods/grid_cache.py, ``cache.preset``):
``paper`` is the paper's grid, the CPU-sized default stays the default, overrides apply
after the preset, and the preset shows in a run's label."""

from __future__ import annotations

import pytest

from jobs.protocol.labels import run_label
from renderers.caches.grid_config import MomentGridConfig
from renderers.methods import MethodError, parse_params

#: The grid fields the paper states (Sec. 5) and MomentGridConfig's defaults hold.
PAPER_FIELDS = ("samples_per_vertex", "vertices_per_record", "primary_store_probability")


def test_paper_preset_is_the_papers_grid() -> None:
    config = parse_params("grid-cache", {"cache": {"preset": "paper"}}).cache_config()
    for name in PAPER_FIELDS:
        assert getattr(config, name) == MomentGridConfig.model_fields[name].default, name


def test_default_is_the_cpu_preset_and_differs_from_the_paper() -> None:
    default = parse_params("grid-cache", {})
    named = parse_params("grid-cache", {"cache": {"preset": "cpu"}})
    assert default.cache_config() == named.cache_config()
    assert default.grid_preset() == named.grid_preset() == "cpu"
    paper = parse_params("grid-cache", {"cache": {"preset": "paper"}}).cache_config()
    assert all(getattr(default.cache_config(), n) != getattr(paper, n) for n in PAPER_FIELDS)


def test_overrides_apply_after_the_preset() -> None:
    config = parse_params("grid-cache", {"cache": {"preset": "paper",
                                                   "samples_per_vertex": 16}}).cache_config()
    assert (config.samples_per_vertex, config.vertices_per_record) == (16, 4)


def test_unknown_preset_is_refused_with_the_choices() -> None:
    with pytest.raises(MethodError, match=r"unknown cache preset 'gpu'.*'cpu', 'paper'"):
        parse_params("grid-cache", {"cache": {"preset": "gpu"}})


def test_the_preset_is_in_the_label() -> None:
    params = parse_params("grid-cache", {"cache": {"preset": "paper"}})
    assert "preset:paper" in run_label("grid-cache", params.model_dump(mode="json"))
