"""`reproduce nirc fig7` and `fig8` from a stubbed equal-time comparison (the report
itself is tested in tests/renderers/test_registry.py): the rows kept and labelled, the
paper's numbers beside ours, time ratios, the PNG, and verdicts that turn with the
numbers (a planted NIRC above PT is 'does not hold', overlapping intervals and a NIRC
slower than NRC 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig7, nirc_fig8
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

#: PT's and NRC's MRSE (interval +-10 %) and FLIP (3 seeds, +-5 %).
MRSE, FLIP = 1.0, 0.5


def row(row_id: int, label: str, method: str, ms: float, error: float, spp: int = 1,
        estimator: str | None = None, note: str = "") -> SimpleNamespace:
    return SimpleNamespace(id=row_id, label=label, method=method, spp=spp,
                           params={"estimator": estimator} if estimator else {},
                           seconds_per_frame=ms / 1e3, mrse=MRSE * error,
                           mrse_ci95=[0.9 * MRSE * error, 1.1 * MRSE * error],
                           flip=FLIP * error, timing_flags=[], error=error, note=note)


def stub(nirc_error: float, nirc_ms: float, capped: bool = False) -> tuple[Any, Any]:
    """A report whose NIRC rows have ``nirc_error`` times PT's errors, NIRC biased at
    ``nirc_ms`` (NRC: 20 ms), and a store of the rows' seeds; ``capped``: the PT row at
    unbiased NIRC's time reached the calibration's spp cap."""
    rows: dict[int, SimpleNamespace] = {}
    calls = []

    def report(scene: str, store: Any, settings: Any, **kwargs: Any) -> Any:
        calls.append((scene, kwargs))
        spp = [row(1, "paper's PT 1 spp", "pt", 10, 1.0),
               row(2, "paper's PT 2 spp", "pt", 20, 1.0, spp=2),
               row(3, "NRC biased", "nrc", 20, 1.0),
               row(4, "NIRC biased (N_c 4)", "nirc", 2 * nirc_ms, nirc_error, estimator="biased"),
               row(5, "NIRC unbiased (N_c 3,1,1)", "nirc", 40, nirc_error, estimator="unbiased"),
               row(6, "Grid cache (var-bound)", "grid-cache", 30, 1.0)]
        time = [spp[1], row(7, "NIRC biased (N_c 2)", "nirc", nirc_ms, nirc_error,
                            estimator="biased"),
                spp[2], row(8, "paper's PT 2 spp (= NRC time)", "pt", 20, 1.0, spp=2),
                spp[4], row(9, "paper's PT 4 spp (= NIRC unbiased time)", "pt", 40, 1.0, spp=4,
                            note="calibration capped: spp 4 is the largest candidate"
                            if capped else "")]
        time[0] = SimpleNamespace(**{**vars(spp[1]), "label": "paper's PT 2 spp (budget)"})
        rows.update({r.id: r for r in [*spp, *time]})
        return SimpleNamespace(equal_spp=spp, equal_time=time, left_out=[], skipped=[])

    def get_run(run_id: int) -> Any:
        flip = FLIP * rows[run_id].error
        return SimpleNamespace(seed_results=[SimpleNamespace(metrics={"flip_hdr": flip * f})
                                             for f in (0.95, 1.0, 1.05)])

    return report, SimpleNamespace(get_run=get_run, calls=calls)


def test_fig7_keeps_each_run_once_with_the_papers_numbers_and_time_ratios(
        monkeypatch: pytest.MonkeyPatch) -> None:
    report, store = stub(0.2, 20)
    monkeypatch.setattr(nirc_fig7, "comparison_report", report)
    result = nirc_fig7.measure(Context(nirc_fig7.QUICK, store, None))
    assert [scene for scene, _ in store.calls] == list(nirc_fig7.SCENES)
    quick = nirc_fig7.QUICK
    assert store.calls[0][1]["allow_loaded"] and store.calls[0][1]["frames"] == quick.frames
    # --quick bounds the report's PT calibrations and says so; --full does not bound them.
    # --quick bounds the report's PT calibrations and renders the verdicts' rows alone
    # (no grid cache, PT at unbiased NIRC's time); --full bounds nothing.
    assert {k: store.calls[0][1][k] for k in ("max_pt_spp", "strongest", "runs", "pt_at")} == \
        {"max_pt_spp": nirc_fig7.QUICK_MAX_PT_SPP, "strongest": nirc_fig7.QUICK_STRONGEST,
         "runs": nirc_fig7.QUICK_RUNS, "pt_at": ("NIRC unbiased",)}
    assert "Grid cache" not in nirc_fig7.QUICK_RUNS
    assert result.settings["PT calibrations"] == \
        "at NIRC unbiased's time, spp candidates up to 32, strongest PT's candidates: none"
    full = nirc_fig7.measure(Context(nirc_fig7.FULL, store, None))
    assert not {"max_pt_spp", "runs", "pt_at"} & set(store.calls[-1][1])
    assert full.settings["PT calibrations"] == "unbounded, at every matched run's time"
    points = [p for p in result.points if p.scene == "white-room"]
    assert [p.run_id for p in points] == [1, 2, 3, 4, 5, 6, 7, 8, 9]
    assert points[6].series == "NIRC biased (N_c 2) (= paper's PT 2 spp time)"
    by_label = {p.series: p for p in points}
    assert by_label["paper's PT 1 spp"].paper == {"mrse": 55.75, "flip": 0.35,
                                                  "ms_per_frame": 24.9, "time_ratio": 1.0}
    assert by_label["NIRC unbiased (N_c 3,1,1)"].paper["time_ratio"] == pytest.approx(56.4 / 24.9)
    assert by_label["paper's PT 2 spp (= NRC time)"].paper == {}
    assert by_label["NIRC unbiased (N_c 3,1,1)"].values["time_ratio"].value == pytest.approx(4.0)
    flip = by_label["NRC biased"].values["flip"]
    assert flip.value == FLIP and flip.ci95[0] < FLIP < flip.ci95[1]
    assert [v.verdict for v in result.verdicts] == ["holds"] * 3


@pytest.mark.parametrize(("nirc_error", "nirc_ms", "expected"), [
    (2.0, 20, ["does not hold"] * 3),                       # planted: NIRC worse than both
    (0.95, 20, ["not comparable"] * 3),                     # intervals overlap
    (0.2, 30, ["holds", "holds", "not comparable"]),        # NIRC 1.5x NRC's time
])
def test_fig7_verdicts_follow_the_numbers(nirc_error: float, nirc_ms: float,
                                          expected: list[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    report, store = stub(nirc_error, nirc_ms)
    monkeypatch.setattr(nirc_fig7, "comparison_report", report)
    verdicts = nirc_fig7.measure(Context(nirc_fig7.QUICK, store, None)).verdicts
    assert [v.verdict for v in verdicts] == expected
    if nirc_ms == 30:
        assert "fastest 1.50x" in verdicts[2].reason


def test_a_win_against_a_capped_pt_row_decides_nothing(monkeypatch: pytest.MonkeyPatch
                                                       ) -> None:
    """PT capped below equal time favours NIRC: its win there is 'not comparable' (the
    same numbers against an uncapped row hold, above); a loss still does not hold."""
    for nirc_error, expected in ((0.2, "not comparable"), (2.0, "does not hold")):
        report, store = stub(nirc_error, 20, capped=True)
        monkeypatch.setattr(nirc_fig7, "comparison_report", report)
        result = nirc_fig7.measure(Context(nirc_fig7.QUICK, store, None))
        assert result.verdicts[0].verdict == expected
        assert any(p.series.endswith(nirc_fig7.CAPPED) for p in result.points)
        assert ("capped below equal time" in result.verdicts[0].reason) == (nirc_error < 1)


def test_fig8_is_the_comparison_on_door_without_the_papers_numbers_drawn(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    report, store = stub(2.0, 20)
    monkeypatch.setattr(nirc_fig7, "comparison_report", report)
    result, paths = reproduce("nirc", "fig8", "quick", tmp_path, store, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"   # drawn as Fig. 7 is
    assert {p.scene for p in result.points} == {"door"}
    assert all(p.paper == {} for p in result.points)
    assert [v.verdict for v in result.verdicts] == ["does not hold"]
    # --quick: the verdict's runs, no PT calibrated at a matched time.
    assert (store.calls[0][1]["runs"], store.calls[0][1]["pt_at"]) == (nirc_fig8.QUICK_RUNS, ())
    assert store.calls[0][1]["allow_loaded"]
    assert result.settings["PT calibrations"] == "none (no equal-time PT rows)"
