"""Validation of the film resolution a caller asks for.

A resolution is an ``int`` (square image) or a ``(width, height)`` pair; both
sides must lie in ``1..MAX_RESOLUTION``. The upper bound is a guard against
typos (``--res 25600``) allocating gigabytes of film, not a Mitsuba limit.
"""

from __future__ import annotations

from renderers.scenes.errors import SceneError

MAX_RESOLUTION = 8192
DEFAULT_RESOLUTION = (256, 256)

Resolution = tuple[int, int]


def _side(value: object, what: str) -> int:
    # bool is an int subclass; `True` as a resolution is always a mistake.
    if isinstance(value, bool) or not isinstance(value, int):
        raise SceneError(f"{what} must be an integer, got {value!r}")
    if not 1 <= value <= MAX_RESOLUTION:
        raise SceneError(f"{what} must be in 1..{MAX_RESOLUTION}, got {value}")
    return value


def normalize_resolution(resolution: int | tuple[int, int] | None) -> Resolution | None:
    """Return ``(width, height)``, or None when the caller asked for no override."""
    if resolution is None:
        return None
    if isinstance(resolution, tuple | list):
        if len(resolution) != 2:
            raise SceneError(
                f"resolution must be an int or a (width, height) pair, got {resolution!r}"
            )
        return _side(resolution[0], "resolution width"), _side(resolution[1], "resolution height")
    side = _side(resolution, "resolution")
    return side, side
