"""The soak (jobs.stress.soak): what fails a row, on runs made up to have each fault,
and through the CLI on a method that aborts its render process (planted)."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.stress.soak import SCENES, SoakSettings, run_soak
from tests.service.test_cli import run_cli
from tests.service.test_cli_render_process import aborting_method  # noqa: F401 - fixture

TINY = SoakSettings(resolution=8, frames=4, seeds=2, reference_spp=16)


def _summary(frozen_seeds=None, metrics=None, per_seed=None, quality=None) -> Any:
    return SimpleNamespace(
        timings={"frozen_seeds": frozen_seeds or [
            {"recordings_after_warmup": 3, "recordings_after_frames": 3,
             "recordings_for_growth": 0}]},
        metrics=metrics or {"mrse": 0.1}, per_seed=per_seed or [{"mrse": 0.1}],
        quality=quality or {})


def _soak(summary_or_error: Any) -> Any:
    def render(job):
        if isinstance(summary_or_error, Exception):
            raise summary_or_error
        return summary_or_error
    return run_soak(render, lambda scene: SimpleNamespace(), TINY, ["pt"])


def test_a_clean_run_passes_and_each_fault_fails_its_row(monkeypatch):
    from renderers.methods import get_method

    monkeypatch.setattr(type(get_method("pt")), "applies_to", lambda self, f: (True, ""))
    assert _soak(_summary()).problems() == []
    crashed = _soak(RuntimeError("render failed: the render process was killed by SIGABRT"))
    assert crashed.rows[0].status == "failed" and "SIGABRT" in crashed.problems()[0]
    grown = _soak(_summary(frozen_seeds=[
        {"recordings_after_warmup": 3, "recordings_after_frames": 6,
         "recordings_for_growth": 2}]))
    assert "1 recording(s) after the warm-up" in grown.problems()[0]
    explained = _soak(_summary(frozen_seeds=[
        {"recordings_after_warmup": 3, "recordings_after_frames": 6,
         "recordings_for_growth": 3}]))
    assert explained.problems() == []
    assert "non-finite metric" in _soak(_summary(metrics={"mrse": math.nan})).problems()[0]
    nan_loss = _summary(per_seed=[{"method_stats": {"loss_history": [0.1, math.inf],
                                                    "cache_stats": {}}}])
    assert "non-finite loss" in _soak(nan_loss).problems()[0]


def test_a_method_no_soak_scene_suits_is_a_gap_that_fails(monkeypatch):
    from renderers.methods import get_method

    monkeypatch.setattr(type(get_method("pt")), "applies_to",
                        lambda self, f: (False, "needs something"))
    report = _soak(_summary())
    assert report.rows[0].status == "failed"
    assert report.problems() == [f"pt on None: applies to none of the soak scenes "
                                 f"({'; '.join(f'{s}: needs something' for s in SCENES)})"]


def test_every_registered_method_has_a_soak_scene(mi):
    from jobs.protocol.scene_store import builtin_features
    from jobs.stress.soak import soak_scene
    from renderers.methods import METHODS

    assert all(soak_scene(name, builtin_features)[0] for name in METHODS)


@pytest.mark.slow
def test_the_soak_command_fails_on_a_render_process_that_aborts(tmp_path, aborting_method):  # noqa: F811
    """Planted: a method whose render calls os.abort(): its row fails with the signal,
    the command exits 1 without a traceback; pt beside it passes."""
    proc = run_cli("stress", "--soak", "--method", "abort", "--method", "pt", "--res", "8",
                   "--frames", "3", "--seeds", "2", "--reference-spp", "16", "--json",
                   data_dir=tmp_path / "data", env=aborting_method)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    report = json.loads(proc.stdout)
    rows = {row["method"]: row for row in report["rows"]}
    assert rows["pt"]["status"] == "ok" and rows["pt"]["recordings"]
    assert rows["abort"]["status"] == "failed"
    assert "killed by SIGABRT" in rows["abort"]["problems"][0]
    assert report["problems"] == [f"abort on cornell-box: {rows['abort']['problems'][0]}"]


def test_the_soak_command_refuses_what_does_not_apply(tmp_path):
    from tests.service.test_cli import assert_clean_error

    assert_clean_error(run_cli("stress", "--soak", "--case", "nan-texture",
                               data_dir=tmp_path), "--case")
    assert_clean_error(run_cli("stress", "--soak", "--method", "nope", data_dir=tmp_path),
                       "unknown method")
    assert_clean_error(run_cli("stress", "--method", "pt", data_dir=tmp_path), "--soak")
