"""Sweep ranges as users type them: ``0.05:1.0``, ``0.1:0.5:0.1``, ``1,2,4,8``, ``1:32``.

``a:b`` runs from a to b inclusive in steps of a (so ``--eps 0.05:1.0`` is the
20 values 0.05, 0.10, ..., 1.00 of the NIRC paper's Sec. 6.3 sweep); ``a:b:s``
takes an explicit step; a comma list is taken as written. Arithmetic is done in
decimal, so 0.05 * 20 is exactly 1.0 and the end point is never lost to float
rounding.
"""

from __future__ import annotations

from decimal import Decimal, InvalidOperation

MAX_VALUES = 10_000


class RangeError(ValueError):
    """A malformed sweep range (the message shows the expected forms)."""


def _number(text: str, original: str, integer: bool) -> Decimal:
    try:
        value = Decimal(text.strip())
    except InvalidOperation:
        raise RangeError(f"'{original}': '{text}' is not a number; expected a:b, a:b:step "
                         "or a comma list like 1,2,4") from None
    if value.is_nan():
        raise RangeError(f"'{original}': '{text}' is not a number")
    if not value.is_finite():
        raise RangeError(f"'{original}': values must be finite")
    if integer and value != value.to_integral_value():
        raise RangeError(f"'{original}': '{text}' is not an integer")
    return value


def parse_range(text: str, integer: bool = False) -> list[float] | list[int]:
    """The values of a sweep range (see the module docstring); RangeError if malformed."""
    text = text.strip()
    if not text:
        raise RangeError("empty range; expected a:b, a:b:step or a comma list")
    if ":" in text:
        parts = text.split(":")
        if len(parts) not in (2, 3):
            raise RangeError(f"'{text}': expected a:b or a:b:step")
        start, stop = (_number(p, text, integer) for p in parts[:2])
        step = _number(parts[2], text, integer) if len(parts) == 3 else start
        if step <= 0:
            raise RangeError(f"'{text}': the step must be > 0 (a:b uses a as the step)")
        if stop < start:
            raise RangeError(f"'{text}': the end {stop} is below the start {start}")
        count = int((stop - start) / step) + 1
        if count > MAX_VALUES:
            raise RangeError(f"'{text}': {count} values is more than {MAX_VALUES}")
        values = [start + i * step for i in range(count)]
    else:
        values = [_number(p, text, integer) for p in text.split(",")]
    return [int(v) for v in values] if integer else [float(v) for v in values]
