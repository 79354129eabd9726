"""Sweep range parsing: the paper's eps sweep, explicit steps, lists, bad input."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from jobs.protocol.ranges import RangeError, parse_range


def test_eps_sweep_of_the_paper_has_twenty_values_ending_at_one():
    values = parse_range("0.05:1.0")
    assert len(values) == 20
    assert values[0] == 0.05 and values[-1] == 1.0
    assert values[1] == 0.1 and values[2] == 0.15  # no float drift: 0.15, not 0.15000000000000002


def test_explicit_step_and_lists():
    assert parse_range("0.1:0.5:0.2") == [0.1, 0.3, 0.5]
    assert parse_range("0.1:0.6:0.2") == [0.1, 0.3, 0.5]  # the end is not overshot
    assert parse_range("1,2,4,8", integer=True) == [1, 2, 4, 8]
    assert parse_range("1:32", integer=True) == list(range(1, 33))
    assert parse_range("0.5") == [0.5]


@pytest.mark.parametrize("text", ["", "a:b", "0.1:", ":1", "1:2:3:4", "0:1", "1:0.5",
                                  "0.1:1:-0.1", "0.1:1:0", "nan:1", "1,x", "0:1:1e-9"])
def test_malformed_ranges_are_clear_errors(text):
    with pytest.raises(RangeError):
        parse_range(text)


def test_nan_is_not_a_number_and_infinity_not_finite():
    with pytest.raises(RangeError, match="'nan' is not a number"):
        parse_range("0.1,nan")
    with pytest.raises(RangeError, match="values must be finite"):
        parse_range("0.1:inf")


def test_integer_ranges_reject_fractions():
    with pytest.raises(RangeError, match="integer"):
        parse_range("1:4:0.5", integer=True)


@given(st.integers(1, 100), st.integers(1, 200), st.integers(1, 50))
def test_ranges_are_inclusive_and_evenly_spaced(start, length, step):
    """With hundredths as units: a:b:s has floor((b-a)/s)+1 values, each s apart."""
    a, s = start / 100, step / 100
    b = (start + length) / 100
    values = parse_range(f"{a}:{b}:{s}")
    assert len(values) == length // step + 1
    assert values[0] == a and values[-1] <= b + 1e-12
    assert all(abs((v1 - v0) - s) < 1e-9 for v0, v1 in zip(values, values[1:], strict=False))
