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

**A replay only ever sees the input widths and Python values it was recorded with.**
Every call hands ``dr.freeze`` a key made anew for the call (:class:`CallKey`): the
width of each Dr.Jit array among its arguments and the value of each other leaf, so
a call that differs from every recording in any of them records again. Dr.Jit's own
key is not enough, for two reasons (docs/timing.md, "The width rule"):

- it does not key on widths: a replay at other widths takes each kernel's size from
  a heuristic over its inputs' sizes, which may fall back to the recorded size;
- it does not compare a Python value that appeared earlier in the same call's inputs
  (its traversal stores a repeated object as a back-reference, and CPython shares
  one object per small int), so a call whose buffer layout was (lanes, 40, 8)
  replayed the recording of (lanes, 25, 8) next to a cache whose weight matrices
  are 25 and 40 wide, scattered past the recorded buffers and corrupted the heap
  (``scripts/drjit_defects/freeze_dedup_key.py`` shows it in a few lines).

A pass over compacted lanes (a caching frame's vertices and queries) therefore takes
them padded to a :class:`Capacity`, a width that only grows, with headroom over the
counts seen so far: its recordings settle like any other function's.

**A scene enters a frozen call as its arrays** (:class:`SceneArrays`): every call
replaces a scene among its arguments with the scene's pointer arrays and the few
arrays it holds outside its objects, and the function gets the scene back in their
place. Handed the scene object, Dr.Jit walked each of its objects twice per call
(docs/timing.md, "The floor of a frozen call"); a scene nested in another argument
is refused, and the wrapped function's closure never holds one. Where every emitter
Dr.Jit has registered is one of the scene's and its shapes hold them (area lights), the
emitters' pointer array is handed over as a plain array: Dr.Jit's walk of the shapes
already meets every variable of the emitters, and walking the emitters' domain again
cost a quarter of a call (:meth:`SceneLayout.emitters_walked`).

Freezing is on by default; ``with frozen_frames(False):`` runs the same code
unfrozen (to compare the two: the frozen and unfrozen frames of a method must give
the same images).
"""

from __future__ import annotations

import ctypes
import dataclasses
import enum
import functools
import gc
import math
import operator
import os
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
#: Recordings of one frozen function after which Dr.Jit warns (its default, 10, is
#: reached legitimately by a pass whose buffers grow: one recording per layout).
WARN_AFTER = 32


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
        # Dr.Jit walks this function's closure and globals too: neither reaches a scene.
        def keyed(_key: CallKey, *args: Any) -> Any:
            return fn(*(arg.scene if isinstance(arg, SceneArrays) else arg for arg in args))

        # Each width or value of a call records once (the module docstring): a
        # changing count is padded to a Capacity, so a function records a few times.
        self._fn = dr.freeze(keyed, auto_opaque=auto_opaque, warn_after=WARN_AFTER)
        self._scene: SceneLayout | None = None   # of the last scene handed over

    def __call__(self, *args: Any) -> Any:
        # A scene's generation is part of the key: a replay after a mesh moved would use
        # the recorded geometry (tests/renderers/test_animation.py), and one after its
        # emitters changed a light selector's recorded constants.
        generations = tuple(scene_generation(arg) for arg in args if is_scene(arg))
        args = tuple(self._arrays(arg) if is_scene(arg) else arg for arg in args)
        key = CallKey.of((generations, *args))
        # No garbage collection inside a call: collecting another frozen function (an
        # object cycle freed late) while this one records aborted the process.
        collecting = gc.isenabled()
        gc.disable()
        try:
            return self._fn(key, *args)
        finally:
            if collecting:
                gc.enable()

    def recordings(self) -> int:
        return int(self._fn.n_recordings)

    def _arrays(self, scene: Any) -> SceneArrays:
        if self._scene is None or self._scene.scene is not scene:
            self._scene = SceneLayout(scene)
        return self._scene.arrays()


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


class CallKey:
    """What a replay must match of a call besides Dr.Jit's own key: the width (a
    tensor's shape) of every Dr.Jit array in the call's PyTrees and the value of every
    other leaf, in Dr.Jit's order of traversal (tuples, lists, dicts, ``DRJIT_STRUCT``
    and dataclass fields). Made anew for each call, so that Dr.Jit, which compares a
    Python object of the inputs by value only where it meets it first, compares this
    one (it is never a repeat).

    Other objects (a shape, an emitter) enter by type and identity, as Dr.Jit compares
    them; a scene's arrays (:class:`SceneArrays`) by their widths and the count of its
    own arrays. Its objects' arrays are Dr.Jit's to walk, and keep their widths while
    it renders (a scene whose meshes change size is a new scene)."""

    __slots__ = ("parts", "_hash")

    def __init__(self, parts: tuple[Any, ...]) -> None:
        self.parts = parts
        self._hash = hash(parts)

    @classmethod
    def of(cls, tree: Any) -> CallKey:
        parts: list[Any] = []
        _collect(tree, parts)
        return cls(tuple(parts))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CallKey) and self.parts == other.parts

    def __hash__(self) -> int:
        return self._hash

    def __repr__(self) -> str:
        return f"CallKey{self.parts}"


def _collect(node: Any, parts: list[Any]) -> None:
    """Append ``node``'s widths and leaf values to ``parts`` (:class:`CallKey`)."""
    kind = _KINDS.get(type(node))
    if kind is None:
        kind = _KINDS[type(node)] = _kind(type(node))
    if kind is _Kind.VALUE:
        parts.append(node)
    elif kind is _Kind.ARRAY:
        parts.append(dr.width(node))
    elif kind is _Kind.TENSOR:
        parts.append(tuple(node.shape))
    elif kind is _Kind.SEQUENCE:
        parts.append(len(node))
        for item in node:
            _collect(item, parts)
    elif kind is _Kind.DICT:
        for name, value in node.items():
            parts.append(name)
            _collect(value, parts)
    elif kind is _Kind.OWN_ARRAYS:   # Dr.Jit compares their count, and so does the key
        parts.append(len(node.indices))
    elif kind is _Kind.OBJECT:
        if is_scene(node):
            raise TypeError("a frozen call's inputs hold a scene inside another value: "
                            "hand the scene over as an argument of its own (it enters "
                            "as its arrays, SceneArrays)")
        # Compared by identity, as Dr.Jit compares it; not kept alive.
        parts.append((type(node).__qualname__, id(node)))
    else:   # a DRJIT_STRUCT's or a dataclass's fields
        for value in kind(node):
            _collect(value, parts)


class _Kind(enum.Enum):
    """How :func:`_collect` enters a value, by its type (a struct or a dataclass by the
    getter of its fields' values)."""

    ARRAY = enum.auto()
    TENSOR = enum.auto()
    SEQUENCE = enum.auto()
    DICT = enum.auto()
    VALUE = enum.auto()
    OWN_ARRAYS = enum.auto()
    OBJECT = enum.auto()


def _kind(cls: type) -> _Kind | Callable[[Any], tuple[Any, ...]]:
    """How :func:`_collect` enters an instance of ``cls`` (the first that applies:
    Dr.Jit array, tuple or list, dict, ``DRJIT_STRUCT``, dataclass, value, ...)."""
    if dr.is_array_v(cls):
        return _Kind.TENSOR if dr.is_tensor_v(cls) else _Kind.ARRAY
    if issubclass(cls, tuple | list):
        return _Kind.SEQUENCE
    if issubclass(cls, dict):
        return _Kind.DICT
    if (fields := getattr(cls, "DRJIT_STRUCT", None)) is not None:
        return _fields(tuple(fields))
    if dataclasses.is_dataclass(cls) and not issubclass(cls, type):
        return _fields(tuple(field.name for field in dataclasses.fields(cls)))
    if issubclass(cls, _VALUES):
        return _Kind.VALUE
    return _Kind.OWN_ARRAYS if issubclass(cls, OwnArrays) else _Kind.OBJECT


#: Leaves compared by value (anything else by identity).
_VALUES = (int, float, complex, str, bytes, type(None), enum.Enum)
#: :func:`_kind` of each type met so far.
_KINDS: dict[type, _Kind | Callable[[Any], tuple[Any, ...]]] = {}


def _fields(names: tuple[str, ...]) -> Callable[[Any], tuple[Any, ...]]:
    """The values of an object's fields ``names``, as a tuple."""
    if len(names) > 1:
        return operator.attrgetter(*names)
    return lambda node: tuple(getattr(node, name) for name in names)


#: Geometry generations of scenes by ``id``: bumped by :func:`geometry_changed`.
_GEOMETRY: dict[int, int] = {}
#: The emitters' and shapes' state of scenes by ``id``: set by :func:`lights_changed`.
_LIGHTS: dict[int, str] = {}
#: Camera generations of scenes by ``id``: bumped by :func:`camera_changed`.
_CAMERA: dict[int, int] = {}


def geometry_changed(scene: Any) -> None:
    """Say that ``scene``'s mesh vertices changed (``params.update()``): frozen calls
    given it record again. Measured with Mitsuba 3.9.1: a replay after a mesh's
    ``vertex_positions`` changed rendered the old geometry in part (the moved box's
    pixels differed from a traced render by up to 0.13), while a changed ``to_world`` of
    a shape or a changed radiance was followed."""
    _GEOMETRY[id(scene)] = _GEOMETRY.get(id(scene), 0) + 1


def lights_changed(scene: Any, state: str) -> None:
    """Say that ``scene``'s emitters and shapes are now in the state named ``state``
    (``params.update()``): light selectors built for another state are built again
    (renderers.integrators.lights.current_sampler: their power and position tables
    would be stale), and frozen calls replay a recording of this state, or record one
    (a recording holds some of those tables as constants)."""
    _LIGHTS[id(scene)] = state


def camera_changed(scene: Any) -> None:
    """Say that ``scene``'s sensor parameters changed (``params.update()``): what was
    derived from the camera for another generation (ReSTIR's projection of the previous
    frame's points) is derived again."""
    _CAMERA[id(scene)] = _CAMERA.get(id(scene), 0) + 1


def camera_generation(scene: Any) -> int:
    """How many times ``scene``'s camera changed (:func:`camera_changed`)."""
    return _CAMERA.get(id(scene), 0)


def scene_generation(scene: Any) -> tuple[int, str]:
    """What a recording or a light selector of ``scene`` was made for: its geometry
    generation and its emitters' and shapes' state."""
    return _GEOMETRY.get(id(scene), 0), _LIGHTS.get(id(scene), "")


def is_scene(value: Any) -> bool:
    """Whether ``value`` is a Mitsuba scene (of any variant)."""
    return any(cls.__name__ == "Scene" and cls.__module__ == "mitsuba"
               for cls in type(value).__mro__)


def object_traversal() -> Any:
    """The block in which Mitsuba's objects list their Dr.Jit arrays (they list none
    outside it, where a loop or a virtual call would walk them by mistake)."""
    return dr.scoped_set_flag(dr.JitFlag.EnableObjectTraversal, True)


class SceneArrays:
    """What a frozen call is handed of a scene: its pointer arrays (of its shapes,
    emitters and sensors) and its own arrays (:class:`OwnArrays`). Dr.Jit walks the
    fields of ``DRJIT_STRUCT`` only, so it never meets :attr:`scene`, which the frozen
    function gets in this value's place.

    Handed the scene itself, Dr.Jit walks every object of the scene twice per call:
    once through the scene's own traversal and once through its registry, which it
    walks for the pointer arrays it met (docs/timing.md, "The floor of a frozen call").
    The registry walk alone covers every shape, emitter and sensor (and what they
    hold: meshes, textures, BSDFs, the film), and the pointer arrays make Dr.Jit take
    it."""

    DRJIT_STRUCT = {"shapes": object, "emitters": object, "sensors": object, "own": object}

    def __init__(self, scene: Any, own: OwnArrays, walk_emitters: bool = True) -> None:
        self.scene = scene
        self.shapes = _pointers(scene.shapes_dr())
        self.emitters = _pointers(scene.emitters_dr())
        self.sensors = _pointers(scene.sensors_dr())
        if self.emitters is not None and not walk_emitters:
            # An input still, but as a plain array: Dr.Jit does not walk the emitters'
            # domain for it (SceneLayout.emitters_walked says when that is right).
            own = OwnArrays([*own.indices, self.emitters.index])
            self.emitters = None
        self.own = own


def _pointers(array: Any) -> Any:
    """A scene's pointer array, or None for an empty one: a scene without emitters has
    an emitter array of width 0 that is no Dr.Jit variable (index 0), which a frozen
    call's input walk takes for one and aborts on ("jit_var(r0): unknown variable!")."""
    return array if dr.width(array) else None


class OwnArrays:
    """The Dr.Jit variables a scene holds outside its shapes, emitters and sensors,
    listed to Dr.Jit by their indices (``_traverse_1_cb_ro``): with Mitsuba 3.9 on the
    LLVM backend, the ray-tracing acceleration structure's four (Embree's scene and
    entry points, the shapes' registry ids), which Mitsuba keeps for the scene's life
    (a rebuild after the geometry moved reuses them); and the emitters' and shapes'
    sampling distributions where the scene has them (rebuilt when an emitter
    changes). Each variable is listed as an input, never replaced: the frame reads the
    scene's own."""

    def __init__(self, indices: list[int]) -> None:
        self.indices = indices

    def _traverse_1_cb_ro(self, visit: Callable[[int, str, str], None]) -> None:
        for index in self.indices:
            visit(index, "", "")

    def _traverse_1_cb_rw(self, visit: Callable[[int, str, str], int]) -> None:
        for index in self.indices:
            visit(index, "", "")


class SceneLayout:
    """Where a scene's own arrays (:class:`OwnArrays`) are in its traversal, found once:
    the variables of its traversal that none of its shapes, emitters and sensors holds.
    Those listed before the first of its objects' (the acceleration structure) are kept
    for the scene's life; any after (a sampling distribution, rebuilt with what it
    samples) are read from a walk of the scene on each call, ~0.2 ms on many-lights."""

    def __init__(self, scene: Any) -> None:
        self.scene = scene
        self._find(self._walk())

    def _find(self, walk: list[int]) -> None:
        scene = self.scene
        with object_traversal():
            shapes = set(dr.detail.collect_indices(list(scene.shapes())))
            emitters = set(dr.detail.collect_indices(list(scene.emitters())))
            held = shapes | emitters | set(dr.detail.collect_indices(
                [*scene.sensors(), scene.shapes_dr(), scene.emitters_dr(),
                 scene.sensors_dr()]))
        #: Whether Dr.Jit's walk of the shapes meets every variable of the emitters
        #: (each an area light, which its shape holds).
        self.emitters_in_shapes = emitters <= shapes
        self.emitter_addresses = frozenset(emitter.ptr for emitter in scene.emitters())
        own = [at for at, index in enumerate(walk) if index and index not in held]
        first_held = next((at for at, index in enumerate(walk) if index in held), len(walk))
        self.length = len(walk)
        self.kept = [walk[at] for at in own if at < first_held]
        self.rebuilt = [at for at in own if at > first_held]

    def _walk(self) -> list[int]:
        with object_traversal():
            return dr.detail.collect_indices(self.scene)

    def arrays(self) -> SceneArrays:
        """The scene's arrays now."""
        if not self.rebuilt:
            return SceneArrays(self.scene, OwnArrays(self.kept), self.emitters_walked())
        walk = self._walk()
        if len(walk) != self.length:   # a distribution appeared or went: find them anew
            self._find(walk)
        return SceneArrays(self.scene, OwnArrays(
            self.kept + [walk[at] for at in self.rebuilt if walk[at]]),
            self.emitters_walked())

    def emitters_walked(self) -> bool:
        """Whether a call must have Dr.Jit walk the emitters' domain: unless every
        emitter registered with Dr.Jit is one of this scene's and its shapes' walk meets
        all their variables. A call over the emitters traces every registered one, and a
        variable of any that is no input makes the recording fail (another scene's
        environment map, alive in the process); a call with the other layout of inputs
        records anew. Measured on many-lights (32 area lights), a frozen call that does
        nothing but take the scene: 1.02 ms walking the emitters, 0.78 ms not."""
        return not (self.emitters_in_shapes
                    and registered_emitters() == self.emitter_addresses)


@functools.cache
def _registry_functions() -> tuple[Any, Any] | None:
    """Dr.Jit's ``jit_registry_id_bound`` and ``jit_registry_get_pointers`` (its C++
    symbols; None where this Dr.Jit has none by those names)."""
    try:
        core = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
        bound = core._Z21jit_registry_id_boundPKcS0_
        pointers = core._Z25jit_registry_get_pointersPKcS0_PPv
    except (OSError, AttributeError):
        return None
    bound.restype, bound.argtypes = ctypes.c_uint32, [ctypes.c_char_p, ctypes.c_char_p]
    pointers.restype = None
    pointers.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
    return bound, pointers


def registered_emitters() -> frozenset[int] | None:
    """The addresses of the emitters registered with Dr.Jit for the current Mitsuba
    variant, which a call over the emitters traces (None: this Dr.Jit does not say, or
    the variant is not an LLVM one: handing the emitters over without their walk was
    measured and compared with traced renders on the LLVM backend only)."""
    import mitsuba as mi

    functions = _registry_functions()
    if functions is None or not (mi.variant() or "").startswith("llvm"):
        return None
    bound, pointers = functions
    variant, domain = mi.variant().encode(), b"Emitter"
    slots = (ctypes.c_void_p * bound(variant, domain))()
    pointers(variant, domain, slots)
    return frozenset(address for address in slots if address)


#: Bytes a frozen call's input mapped from host memory is aligned to: Dr.Jit marks a
#: mapped array unaligned when its address is not a multiple of min(64, vector width x
#: item size) bytes, and that mark is part of the call's key.
HOST_ALIGNMENT = 64


def host_floats(values: Any) -> Any:
    """``values`` (host numbers, e.g. a NumPy array) as a flat ``mi.Float`` that a frozen
    call can take every frame without recording again.

    Built from a contiguous NumPy array, a Dr.Jit array on the LLVM backend maps the
    array's memory instead of copying it, and flags it unaligned unless its address is
    a multiple of min(64, vector width x item size) bytes. The flag is part of the key
    of a frozen call, and NumPy aligns its allocations to 16 bytes only: arrays
    uploaded anew each frame (`cv-vmf`'s lobes after each fit) met a new pattern of
    flags every few frames, and each pattern recorded again (measured: 4-7 recordings
    in 10 frames after the warm-up). Copied into a buffer aligned to
    :data:`HOST_ALIGNMENT`, the values are mapped aligned whatever NumPy allocates."""
    import mitsuba as mi
    import numpy as np

    flat = np.asarray(values, dtype=np.float32).ravel()
    itemsize = flat.dtype.itemsize
    buffer = np.empty(flat.size + HOST_ALIGNMENT // itemsize, dtype=np.float32)
    start = (-buffer.ctypes.data % HOST_ALIGNMENT) // itemsize
    aligned = buffer[start:start + flat.size]
    aligned[...] = flat
    return mi.Float(aligned)


class Capacity:
    """A width for a count that changes from call to call (a compaction's), that only
    grows: padded to it, a frozen pass sees the same few widths and records once per
    width (the module docstring).

    The count is a sum over ``lanes`` independent paths, so its spread between frames
    is about ``count / sqrt(lanes)`` (a path's count of cache vertices or queries has a
    standard deviation about its mean; measured on sky at 32x32, 1024 lanes: vertex
    counts 2063 to 2344 over 60 frames, 3 %). When a count exceeds the capacity, the
    capacity becomes the count times ``1 + 1/16 + 5 / sqrt(lanes)`` (five spreads, and
    a sixteenth for counts that drift as a cache trains), rounded up to 16 lanes and at
    most ``most``, the count's bound: 11 % over the count at 128x128, 22 % at 32x32."""

    ROUND = 16

    def __init__(self, lanes: int) -> None:
        self.headroom = 1 / 16 + 5 / math.sqrt(max(lanes, 1))
        self.width = 0

    def fit(self, count: int, most: int) -> int:
        """The width to pad ``count`` lanes to (``count`` <= ``most``)."""
        if count > self.width:
            wanted = math.ceil(count * (1 + self.headroom))
            rounded = -(-wanted // self.ROUND) * self.ROUND
            self.width = max(count, min(rounded, most))
        return self.width


def padded(indices: Any, width: int) -> Any:
    """``indices`` (e.g. a ``dr.compress`` result) repeated at its last entry up to
    ``width``: the extra lanes redo the last entry's work and write the same values
    to the same places."""
    count = dr.width(indices)
    if width == count:
        return indices
    at = dr.minimum(dr.arange(type(indices), width), count - 1)
    return dr.gather(type(indices), indices, at)
