"""Equal-time calibration (jobs/protocol/calibration.py) with fake timings: no rendering.

Each fake ``measure`` records the order of the calls, so the tests see which
candidates are timed, that the budget is re-measured between rounds, and
which value was chosen from the medians.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import pytest
from rich.console import Console

from jobs.protocol.calibration import calibrate, calibrate_job, caveats
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import RenderSpec, TimeBudget
from renderers.methods.base import Knob
from renderers.methods.nirc import with_nc_at_v1
from renderers.methods.pt import SPP_CANDIDATES
from service.tables import calibration_table


class Clock:
    """Fake timings: ``times[value]`` is a list cycled over rounds (or one number)."""

    def __init__(self, times: dict[int, float | list[float]],
                 budget: float | list[float] | None = None) -> None:
        self.times = {k: itertools.cycle(v if isinstance(v, list) else [v])
                      for k, v in times.items()}
        self.budgets = itertools.cycle(budget if isinstance(budget, list) else [budget])
        self.calls: list[str] = []

    def measure(self, value: int) -> float:
        self.calls.append(f"nc={value}")
        return next(self.times[value])

    def budget(self) -> float:
        self.calls.append("budget")
        return next(self.budgets)


def test_every_candidate_is_timed_and_the_largest_fitting_median_wins():
    clock = Clock({1: 0.012, 2: 0.014, 4: 0.018, 8: 0.026, 16: 0.042})
    record = calibrate("nc", [8, 1, 2, 4, 16], clock.measure, 0.018, budget_source="test",
                       tolerance_s=0.0005, rounds=1)
    assert record.chosen == 4 and record.fits and not record.capped and not record.unstable
    # The old search stopped at the first candidate over budget (8); every one is timed.
    assert clock.calls == ["nc=1", "nc=2", "nc=4", "nc=8", "nc=16"]
    assert record.to_json()["measured_s"]["8"] == pytest.approx(0.026)
    none = calibrate("nc", [1, 2], lambda nc: 1.0, 0.5, budget_source="test")
    assert none.chosen == 1 and not none.fits and not none.capped
    with pytest.raises(ValueError):
        calibrate("nc", [], clock.measure, 1.0, budget_source="test")


def test_non_monotone_times_choose_a_larger_candidate_past_a_slow_one():
    """With BTH more neural samples can stop paths earlier: 8 is slower than 16."""
    clock = Clock({1: 0.010, 2: 0.012, 4: 0.016, 8: 0.025, 16: 0.019, 32: 0.030})
    record = calibrate("nc", [1, 2, 4, 8, 16, 32], clock.measure, 0.020,
                       budget_source="test", rounds=3)
    assert record.chosen == 16          # the old walk stopped at 8 and chose 4
    assert set(record.measured_s) == {1, 2, 4, 8, 16, 32} and not record.not_timed
    # Declared monotone, the same timings stop the search at 8 (25 ms: clearly over).
    clock = Clock({1: 0.010, 2: 0.012, 4: 0.016, 8: 0.025, 16: 0.019, 32: 0.030})
    record = calibrate("nc", [1, 2, 4, 8, 16, 32], clock.measure, 0.020,
                       budget_source="test", rounds=3, monotone=True)
    assert record.chosen == 4 and set(record.not_timed) == {16, 32}


LINEAR = {spp: 0.010 * spp for spp in SPP_CANDIDATES}     # 10 ms per sample per pixel


def test_a_monotone_knob_stops_above_the_first_candidate_clearly_over():
    """spp 4 (40 ms) is over the 35 ms budget by more than the allowed 3.5 ms: nothing
    above it is timed; spp 3 (30 ms) is under it by as much: after the first round
    nothing below it is timed again. Without the flag every candidate under the 4x
    cut is timed in every round."""
    clock = Clock(LINEAR)
    record = calibrate("spp", SPP_CANDIDATES, clock.measure, 0.035, budget_source="test",
                       rounds=3, monotone=True, probe_frames=5)
    assert record.chosen == 3 and record.fits and not record.unstable
    assert clock.calls == ["nc=1", "nc=2", "nc=3", "nc=4", "nc=4", "nc=3", "nc=3", "nc=4"]
    assert record.probes_per_round == [4, 2, 2] and record.timed_frames == 8 * 5
    assert set(record.not_timed) == set(SPP_CANDIDATES) - {1, 2, 3, 4}
    assert "spp 4 is over the budget" in record.not_timed[512]
    assert record.to_json()["not_timed"]["6"] == record.not_timed[6]
    # Under a 31 ms budget spp 3 fits by less than the allowed 3.1 ms: spp 2, not 3,
    # is the candidate below which nothing is timed again.
    near = Clock(LINEAR)
    assert calibrate("spp", SPP_CANDIDATES, near.measure, 0.031, budget_source="test",
                     rounds=3, monotone=True).chosen == 3
    assert [near.calls.count(f"nc={v}") for v in (1, 2, 3, 4)] == [1, 3, 3, 3]
    unflagged = Clock(LINEAR)
    calibrate("spp", SPP_CANDIDATES, unflagged.measure, 0.035, budget_source="test",
              rounds=3)
    assert sorted(unflagged.calls) == sorted(3 * [f"nc={v}" for v in (1, 2, 3, 4, 6, 8, 12)])


def test_no_candidate_predicted_over_four_budgets_is_timed():
    """A non-monotone knob keeps its full search except this cut: from nc 1, 2 and 4
    the log-log line predicts 80 ms for nc 8, over 4 x 15 ms; a candidate timed over
    the cut is not timed again."""
    clock = Clock({1: 0.010, 2: 0.020, 4: 0.040, 8: 0.080, 16: 0.160, 32: 0.320})
    record = calibrate("nc", [1, 2, 4, 8, 16, 32], clock.measure, 0.015,
                       budget_source="test", rounds=3)
    assert record.chosen == 1 and set(record.measured_s) == {1, 2, 4}
    assert set(record.not_timed) == {8, 16, 32}
    assert record.not_timed[8].startswith("predicted 80 ms per frame")
    assert clock.calls.count("nc=4") == 3
    once = Clock({1: 0.010, 2: 0.100})
    record = calibrate("nc", [1, 2], once.measure, 0.012, budget_source="test", rounds=3)
    assert once.calls == ["nc=1", "nc=2", "nc=1", "nc=1"] and record.spread_s[2] == [0.1, 0.1]


def test_noise_does_not_stop_a_monotone_search_too_early():
    """spp 4's first round is slow (25 ms against a 20 ms budget, allowed spread 2 ms):
    the search stops above it, but its next round (12 ms) puts spp 8 back in play,
    which then gets its rounds and is chosen. A candidate over the limit by less than
    the allowed spread (spp 8 at 21 ms in its first round) does not stop it either."""
    clock = Clock({1: 0.005, 2: 0.008, 4: [0.025, 0.012, 0.012], 8: [0.021, 0.019, 0.019],
                   16: 0.030, 32: 0.060})
    record = calibrate("spp", [1, 2, 4, 8, 16, 32], clock.measure, 0.020,
                       budget_source="test", rounds=3, monotone=True)
    assert record.chosen == 8 and record.measured_s[4] == pytest.approx(0.012)
    assert clock.calls.count("nc=8") == 3 and clock.calls.count("nc=16") == 3
    assert set(record.not_timed) == {32} and len(record.probes_per_round) == 5
    assert clock.calls[:4] == ["nc=1", "nc=2", "nc=4", "nc=4"]   # spp 8 waited for round 2


def test_a_fitting_top_candidate_is_reported_as_capped():
    """'PT 512 spp = NRC time' silently hit the top of the candidates."""
    record = calibrate("spp", [1, 64, 512], lambda spp: 1e-5 * spp, 0.5,
                       budget_source="test", rounds=2)
    assert record.chosen == 512 and record.fits and record.capped
    assert any(reason.startswith("capped") for reason in record.reasons)
    assert record.to_json()["capped"] is True


def test_budget_and_candidates_are_interleaved_over_rounds_and_medians_decide():
    # nc 4 is over budget in one round of three (a spike): the median says it fits.
    clock = Clock({1: 0.010, 2: 0.014, 4: [0.0195, 0.030, 0.0195]},
                  budget=[0.020, 0.021, 0.019])
    record = calibrate("nc", [1, 2, 4], clock.measure, clock.budget, budget_source="test",
                       tolerance_s=0.001, rounds=3, max_spread=1.0)
    assert clock.calls == ["budget", "nc=1", "nc=2", "nc=4",
                           "budget", "nc=4", "nc=2", "nc=1",
                           "budget", "nc=1", "nc=2", "nc=4"]
    assert record.order == clock.calls
    assert record.budget_s == pytest.approx(0.020)       # median of the three rounds
    assert record.budget_spread_s == pytest.approx([0.019, 0.021])
    assert record.measured_s[4] == pytest.approx(0.0195)
    assert record.spread_s[4] == pytest.approx([0.0195, 0.030])
    assert record.chosen == 4 and not record.unstable   # max_spread 1.0: a wide allowance


def test_a_spread_across_the_limit_is_flagged_unstable():
    # nc 4's rounds disagree about fitting the 20 ms budget and spread 10 ms > 10 % of it.
    clock = Clock({1: 0.010, 2: 0.014, 4: [0.015, 0.025, 0.019]}, budget=0.020)
    record = calibrate("nc", [1, 2, 4], clock.measure, clock.budget, budget_source="test",
                       tolerance_s=0.001, rounds=3)
    assert record.unstable and record.chosen == 4
    assert any("nc 4 spreads" in reason for reason in record.reasons)
    # A noisy candidate far from the limit cannot change the choice: not flagged.
    quiet = Clock({1: [0.001, 0.009, 0.005], 2: 0.014}, budget=0.020)
    assert not calibrate("nc", [1, 2], quiet.measure, quiet.budget, budget_source="test",
                         rounds=3).unstable
    # A budget that itself jumps is flagged.
    jumpy = Clock({1: 0.010}, budget=[0.020, 0.030, 0.020])
    record = calibrate("nc", [1], jumpy.measure, jumpy.budget, budget_source="test", rounds=3)
    assert record.unstable and any("budget's spread" in r for r in record.reasons)
    # An unstable calibration says what to do about it, and a report row says it was.
    assert record.reasons[-1].startswith("what to do:")
    assert caveats(record.to_json())[-1] == (
        "calibration unstable: the machine's timing noise could change the choice")


def test_a_loaded_or_capped_calibration_says_so():
    clock = Clock({1: 0.010, 2: 0.012}, budget=0.020)
    record = calibrate("nc", [1, 2], clock.measure, 0.020, budget_source="test")
    record.note_load({"loaded": True, "reasons": ["tasks waited for a core 40 % of the time"]})
    assert record.loaded and record.capped and not record.unstable
    assert "loaded: tasks waited for a core 40 % of the time" in record.reasons
    assert any(r.startswith("what to do:") for r in record.reasons)
    assert [c.split(":")[0] for c in caveats(record.to_json())] == [
        "calibration capped", "machine loaded during the calibration"]
    quiet = calibrate("nc", [1, 2], clock.measure, 0.020, budget_source="test")
    quiet.note_load({"loaded": False, "reasons": []})
    assert quiet.loaded is False and not any("what to do" in r for r in quiet.reasons)


def test_adaptive_nc_keeps_its_later_vertex_count():
    assert with_nc_at_v1({"nc": [8, 1]}, 4) == {"nc": [4, 1]}
    assert with_nc_at_v1({"nc": [8]}, 4) == {"nc": [4]}
    assert with_nc_at_v1({}, 2) == {"nc": [2]}


def test_calibrate_job_keeps_the_later_vertex_nc(monkeypatch):
    """calibrate_job with a fake method: nc=[8, 1] is probed and returned as [N, 1]."""
    import renderers.methods as methods

    seen: list[list[int]] = []
    real = methods.get_method("nirc")

    class FakeMethod:
        params = real.params

        def render(self, scene, values, seed_parts, spp, frames):
            seen.append(list(values.nc))
            seconds = 0.001 * values.nc[0]

            class Output:
                timings = {"frame_median_s": seconds}
            return Output()

    monkeypatch.setattr(methods, "get_method", lambda name: FakeMethod())
    spec = RenderSpec(scene="cornell-box", method="nirc",
                      params={"termination": "adaptive", "nc": [8, 1]},
                      time_budget=TimeBudget(ms=4.5, candidates=[1, 2, 4, 8], rounds=2))
    calibrated, record = calibrate_job(RenderJob.parse(spec), scene=None, device_key="test")
    assert calibrated.spec.params["nc"] == [4, 1] and record.chosen == 4
    assert calibrated.params.nc == [4, 1] and calibrated.spec.time_budget is None
    assert all(nc[1:] == [1] for nc in seen) and len(seen) == 8   # 4 candidates x 2 rounds


def test_calibrate_job_stops_the_spp_search_and_reports_its_cost(monkeypatch):
    """pt's spp knob is monotone by default (nirc's N_c is not): at 1 ms per spp and a
    4.5 ms budget the probes stop at spp 6, and the second round skips what is below
    spp 4 (under the budget by more than the allowed spread)."""
    seen = _fake_pt(monkeypatch, lambda spp, seen: {"frame_median_s": 0.001 * spp})
    spec = RenderSpec(scene="cornell-box", method="pt",
                      time_budget=TimeBudget(ms=4.5, rounds=2, probe_frames=2))
    calibrated, record = calibrate_job(RenderJob.parse(spec), scene=None, device_key="test")
    assert calibrated.spec.spp == record.chosen == 4 and record.monotone
    assert seen == [1, 2, 3, 4, 6, 6, 4]
    assert record.timed_frames == 7 * 2 and record.wall_s > 0
    console = Console(width=400, record=True)
    console.print(calibration_table("calibration", record.to_json()))
    text = console.export_text()
    assert "spp 8, 12, 16" in text and "14 timed frames" in text
    assert "3: 3 [3, 3] (1 of 2 rounds)" in text and "4: 4 [4, 4]," in text
    assert Knob("spp", (1,)).monotone and not Knob("nc", (1,)).monotone
    assert not Knob("spp", (1,), monotone=False).monotone


def _fake_pt(monkeypatch, timings_of) -> list[int]:
    """pt's parameters with a render whose timings are ``timings_of(spp, seen)``
    (``seen``: the spp of every probe so far, this one included); returns ``seen``."""
    import renderers.methods as methods

    seen: list[int] = []
    real = methods.get_method("pt")

    class FakeMethod:
        params = real.params

        def render(self, scene, values, seed_parts, spp, frames):
            seen.append(spp)
            return SimpleNamespace(timings=timings_of(spp, seen))

    monkeypatch.setattr(methods, "get_method", lambda name: FakeMethod())
    return seen


def _loaded_probes(monkeypatch, loaded_tries: int) -> list[int]:
    """pt at 1 ms per spp whose first ``loaded_tries`` probes ran on a loaded machine
    (and took 10x as long); returns the spp of every probe taken."""
    def timings(spp: int, seen: list[int]) -> dict:
        loaded = len(seen) <= loaded_tries
        return {"frame_median_s": 0.001 * spp * (10 if loaded else 1),
                "load": {"loaded": loaded,
                         "reasons": ["tasks waited for a core 60 %"] if loaded else []}}

    return _fake_pt(monkeypatch, timings)


@pytest.mark.parametrize("allow_loaded", [False, True])
def test_a_probe_on_a_loaded_machine_is_left_out_unless_allowed(monkeypatch, allow_loaded):
    """The first probe (spp 1) runs loaded at 10 ms: kept, it would rule every spp out
    (10 ms > 4.5 ms at spp 1, the smallest); left out and taken again, the quiet medians
    choose spp 4. Allowed, the loaded probe counts and the record says loaded."""
    seen = _loaded_probes(monkeypatch, 1)
    spec = RenderSpec(scene="cornell-box", method="pt", time_budget=TimeBudget(
        ms=4.5, rounds=1, candidates=[1, 2, 4, 8], allow_loaded=allow_loaded))
    calibrated, record = calibrate_job(RenderJob.parse(spec), scene=None, device_key="test")
    if allow_loaded:
        assert record.loaded and record.left_out == [] and seen[:2] != [1, 1]
        assert record.measured_s[1] == pytest.approx(0.010)
    else:
        assert seen[:2] == [1, 1] and record.loaded is False
        assert record.left_out == ["spp 1: 10 ms left out, machine loaded (tasks waited "
                                   "for a core 60 %)"]
        assert calibrated.spec.spp == record.chosen == 4
        assert "1 probe(s) left out: machine loaded" in caveats(record.to_json())


def test_a_calibration_whose_every_try_is_loaded_stops_with_the_reason(monkeypatch):
    from jobs.protocol.calibration import LOADED_RETRIES, LoadedMachineError
    from service.errors import is_user_error

    _loaded_probes(monkeypatch, LOADED_RETRIES + 1)
    spec = RenderSpec(scene="cornell-box", method="pt",
                      time_budget=TimeBudget(ms=4.5, rounds=1, candidates=[1, 2]))
    with pytest.raises(LoadedMachineError, match="ran on a loaded machine") as caught:
        calibrate_job(RenderJob.parse(spec), scene=None, device_key="test")
    assert is_user_error(caught.value)      # a message, not a traceback
