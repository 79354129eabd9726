"""Frozen frames: a steady-state frame replays its recorded kernels instead of tracing
Python again (Dr.Jit's ``dr.freeze``; docs/timing.md, "Frozen frames").

Tracing a frame's Dr.Jit program in Python costs the same at every resolution: it
is most of a small frame (`pt` at 8x8: 6 ms traced, 0.3 ms frozen). A frozen
function records its kernels on the first calls and then only launches them, with
the Dr.Jit arrays passed as arguments bound to the recorded inputs. What that
demands of a frame function:

- every Dr.Jit value it reads that changes between frames is an **argument** (a
  PyTree): a value held in a Python object and read inside is baked into the
  recording and silently not updated on replay (``tests/renderers/test_frozen.py``
  plants one and catches it);
- no host read-back inside (a branch on a count, ``dr.width`` of a compressed
  array, converting to NumPy): those re-record or go stale.

The recording count settles only after about three calls (the first call records
literals, the next ones make changing literals opaque), so a frozen frame loop warms
up until the count has held over ``SETTLED_CALLS`` calls
(renderers.methods.base.run_frames).

A function whose inputs change width between calls (a caching frame's compacted
vertices and queries) records again whenever a changing width equals the width of
another array of its inputs, the scene's included: Dr.Jit keys a recording on which
inputs share a width (one kernel serves arrays of one width), so such a call does not
match the recordings made without the coincidence. Those passes therefore take their
changing widths padded past every width of their other inputs (:func:`input_widths`,
:func:`distinct_width`); their recordings then settle like any other.

Freezing is on by default; ``with frozen_frames(False):`` runs the same code
unfrozen (to compare the two: the frozen and unfrozen frames of a method must give
the same images).
"""

from __future__ import annotations

import gc
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

import drjit as dr

_ENABLED: ContextVar[bool] = ContextVar("frozen_frames", default=True)

#: Warm-up frames a frozen frame loop renders at most while its recordings settle.
MAX_WARMUP_FRAMES = 12
#: Calls without a new recording after which a frozen frame loop's warm-up ends.
SETTLED_CALLS = 3


@contextmanager
def frozen_frames(enabled: bool) -> Iterator[None]:
    """Freeze the frame functions built in this block (``enabled``) or not."""
    token = _ENABLED.set(enabled)
    try:
        yield
    finally:
        _ENABLED.reset(token)


def freezing() -> bool:
    """Whether frame functions built now are frozen."""
    return _ENABLED.get()


def weak_method(method: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` (a bound method) without a strong reference to its object: an object
    that holds its own frozen method then forms no reference cycle and is freed as soon
    as it is dropped, not by a later garbage collection."""
    ref = weakref.WeakMethod(method)

    def call(*args: Any) -> Any:
        return ref()(*args)

    return call


class Frozen:
    """``fn`` run through ``dr.freeze``; :meth:`recordings` counts its recordings. Build
    one only while :func:`freezing` is on; the unfrozen path is the plain code.

    ``auto_opaque=False`` makes every input opaque from the first call: for a function
    whose inputs alternate between kinds, where Dr.Jit's automatic choice of which
    literals to make opaque found the calls incompatible and recorded again on every
    change of kind. Measured: ReSTIR's history (none, from a frame without history,
    from one with) gave 9 recordings in 12 frames instead of 3; a cache's training
    step, called on its state and on copies of it (``NeuralCache.settle``), recorded
    again after settling (4 instead of 2)."""

    def __init__(self, fn: Callable[..., Any], auto_opaque: bool = True) -> None:
        self._fn = dr.freeze(fn, auto_opaque=auto_opaque)

    def __call__(self, *args: Any) -> Any:
        # No garbage collection inside a call: collecting another frozen function (an
        # object cycle freed late) while this one records aborted the process.
        collecting = gc.isenabled()
        gc.disable()
        try:
            return self._fn(*args)
        finally:
            if collecting:
                gc.enable()

    def recordings(self) -> int:
        return int(self._fn.n_recordings)


class FrozenRecords:
    """A frame's training records as a pure function of the scene and the frame's seed,
    ``records(scene, *arguments(seed))``, frozen where freezing is on (every input
    opaque from the first call: the seeds change every frame). :meth:`settle` repeats
    the last call with the next seed and drops its records (nothing changes), so that
    the recordings settle in a warm-up. Subclasses define :meth:`arguments` and
    :meth:`records`."""

    def __init__(self, frozen: bool | None = None) -> None:
        frozen = freezing() if frozen is None else frozen
        self._fn = (Frozen(weak_method(self.records), auto_opaque=False) if frozen
                    else self.records)
        self._last: tuple[Any, int] | None = None   # for settle()

    def __call__(self, scene: Any, seed: int) -> Any:
        self._last = (scene, seed)
        return self._fn(scene, *self.arguments(seed))

    def arguments(self, seed: int) -> tuple[Any, ...]:
        """The Dr.Jit values :meth:`records` takes after the scene for a frame's seed
        (opaque seeds: a traced call would compile a kernel for every literal seed)."""
        raise NotImplementedError

    def records(self, scene: Any, *arguments: Any) -> Any:
        """The frame's records, reading no Dr.Jit value but its arguments."""
        raise NotImplementedError

    def recordings(self) -> int | None:
        """Recordings of the frozen function (None when it is not frozen)."""
        return self._fn.recordings() if isinstance(self._fn, Frozen) else None

    def settle(self) -> None:
        """The last call again with the next seed, its records dropped."""
        if self._last is not None:
            scene, seed = self._last
            dr.eval(self(scene, seed + 1))
            self._last = (scene, seed)


def input_widths(*inputs: Any) -> frozenset[int]:
    """The widths of the Dr.Jit arrays a frozen function's call walks in ``inputs``: its
    PyTrees and the members of the C++ objects in them (a scene's shapes, emitters,
    sensors, their BSDFs and textures, ...), as ``dr.freeze`` walks them.

    Objects registered for the same classes but not reachable from ``inputs`` (those of
    another scene alive in the process) are walked by a call too and are not counted
    here: a width of theirs can still make a pass record once more."""
    with dr.scoped_set_flag(dr.JitFlag.EnableObjectTraversal, True):
        indices = dr.detail.collect_indices(inputs)
    # Only the width is read: any array type of the backend can hold the index.
    import mitsuba as mi

    probe = mi.UInt32(0)
    return frozenset(dr.width(dr.detail.update_indices(probe, [index & 0xFFFFFFFF]))
                     for index in set(indices))


def distinct_width(width: int, taken: frozenset[int], multiple: int = 1) -> int:
    """The least width >= ``width`` (and >= 2: a one-element array is a kind of its own
    to Dr.Jit) that is not in ``taken`` and whose ``multiple``-fold is not either (the
    lanes a pass derives from it): a changing width padded so that it never equals
    another input's."""
    padded = max(width, 2)
    while padded in taken or (multiple > 1 and padded * multiple in taken):
        padded += 1
    return padded


def padded(indices: Any, width: int) -> Any:
    """``indices`` (e.g. a ``dr.compress`` result) repeated at its last entry up to
    ``width``: the extra lanes redo the last entry's work and write the same values
    to the same places."""
    count = dr.width(indices)
    if width == count:
        return indices
    at = dr.minimum(dr.arange(type(indices), width), count - 1)
    return dr.gather(type(indices), indices, at)
