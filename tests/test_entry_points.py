"""The two ``python -m`` entry points run what they say (in this process, so the fast
subset's coverage sees them)."""

from __future__ import annotations

import runpy

import pytest

from renderers.methods import method_table


def test_python_m_renderers_methods_prints_the_method_table(capsys):
    runpy.run_module("renderers.methods", run_name="__main__")
    assert capsys.readouterr().out == method_table() + "\n"


def test_python_m_service_runs_the_cli(capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", ["nirc-bench", "--help"])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_module("service", run_name="__main__")
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "Usage: nirc-bench" in out and "render" in out
