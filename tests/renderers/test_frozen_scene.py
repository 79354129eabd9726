"""What a frozen call is handed of a scene (renderers.frozen.SceneArrays): its pointer
arrays and its own arrays, never the scene object, so that a replay walks each of the
scene's objects once (through Dr.Jit's registry) and not a second time through the
scene's own traversal; and a frozen frame still follows the scene when it changes."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from renderers.frozen import frozen_frames
from tests.renderers.test_frozen import OneSceneAtATime, render


@pytest.fixture(scope="module")
def scenes(mi):
    return OneSceneAtATime()


class Walked:
    """Dr.Jit's frozen function (what ``dr.freeze`` calls with a call's whole input:
    arguments, closure, globals), noting the Dr.Jit variables its walk of each input
    meets before the registry (``dr.detail.collect_indices`` walks a PyTree and
    Mitsuba's objects as the frozen function's traversal does)."""

    def __init__(self, frozen, walks: list[list[int]]) -> None:
        self._frozen, self._walks = frozen, walks

    def __call__(self, call_input):
        import drjit as dr

        from renderers.frozen import object_traversal

        with object_traversal():
            self._walks.append(dr.detail.collect_indices(call_input))
        return self._frozen(call_input)

    def __getattr__(self, name: str):
        return getattr(self._frozen, name)


@pytest.fixture
def walks(monkeypatch):
    """Every frozen call's input walk, for the functions frozen in the test."""
    import drjit as dr

    walked: list[list[int]] = []
    freeze = dr.freeze

    def noting(*args, **kwargs):
        function = freeze(*args, **kwargs)
        function.frozen = Walked(function.frozen, walked)
        return function

    monkeypatch.setattr(dr, "freeze", noting)
    return walked


def objects_variables(scene) -> set[int]:
    """The variables the scene's shapes, emitters and sensors hold (what the registry
    walk, which the pointer arrays call for, covers)."""
    import drjit as dr

    from renderers.frozen import object_traversal

    with object_traversal():
        return set(dr.detail.collect_indices(
            [*scene.shapes(), *scene.emitters(), *scene.sensors()])) - {0}


def walked_twice(walks: list[list[int]], scene) -> list[int]:
    """Per frozen call, the variables of the scene's objects its input walk met (each is
    walked again by the registry)."""
    held = objects_variables(scene)
    return [len(held.intersection(walk)) for walk in walks]


#: One method per kind of frozen call that reads the scene: a frozen mi.render (pt), a
#: frame of its own (ReSTIR), a caching frame in stages with its training paths (nrc),
#: training records (nvc-lights' VisibilityRecords).
METHODS = ("pt", "restir-di", "nrc", "nvc-lights")


@pytest.mark.parametrize("name", METHODS)
def test_no_frozen_call_walks_the_scene_objects_outside_the_registry(scenes, walks, name):
    output = render(scenes, name, True, frames=2)
    assert output.timings["frozen"]["recordings_after_warmup"] >= 1
    scene = scenes["many-lights"].scene
    # A few are met by chance: Dr.Jit shares one variable among equal literals, so an
    # argument may hold a constant an object holds too.
    assert walks and max(walked_twice(walks, scene)) < 0.01 * len(objects_variables(scene))


def test_a_scene_handed_over_itself_is_walked_twice(scenes, walks, monkeypatch):
    """Planted: the scene handed to the frozen frame as it is (the check that swaps it
    for its arrays answers no). The input walk then meets every variable of the
    scene's objects, which the registry walks again: thousands per call."""
    import renderers.frozen as frozen

    monkeypatch.setattr(frozen, "is_scene", lambda _value: False)
    render(scenes, "pt", True, frames=2)
    scene = scenes["many-lights"].scene
    twice = walked_twice(walks, scene)
    assert min(twice) > 0.9 * len(objects_variables(scene))


def test_a_frozen_call_never_takes_a_scene_inside_another_value(scenes):
    """A scene nested in an argument would be walked whole: refused with a message."""
    from renderers.frozen import Frozen

    with frozen_frames(True):
        frozen = Frozen(lambda _arguments: None)
    with pytest.raises(TypeError, match="argument of its own"):
        frozen({"scene": scenes["many-lights"].scene})


def test_dr_freeze_hands_its_frozen_function_the_arguments_and_the_closure(mi):
    """Pins what the tests above rely on of Dr.Jit 1.5's ``dr.freeze``: its wrapper calls
    ``.frozen`` with one dict holding the call's arguments and the function's closure
    variables; ``collect_indices`` lists a Mitsuba object's variables only while object
    traversal is on, and only the fields of a ``DRJIT_STRUCT``."""
    import drjit as dr

    from renderers.frozen import SceneArrays, object_traversal

    walked: list[list[int]] = []
    captured = mi.Float(7)

    def add(x):
        return x + captured

    function = dr.freeze(add)
    function.frozen = Walked(function.frozen, walked)
    x = mi.Float(1, 2)
    np.testing.assert_array_equal(function(x).numpy(), [8, 9])
    assert {x.index, captured.index} <= set(walked[0])

    scene = mi.load_dict({"type": "scene", "shape": {"type": "sphere"},
                          "light": {"type": "constant"}})
    assert dr.detail.collect_indices(scene) == []
    with object_traversal():
        assert len(dr.detail.collect_indices(scene)) > 3
        arrays = SceneArrays(scene, frozen_own(scene))
        assert scene.shapes_dr().index in dr.detail.collect_indices(arrays)
        assert not objects_variables(scene) & set(dr.detail.collect_indices(arrays))


def frozen_own(scene):
    from renderers.frozen import SceneLayout

    return SceneLayout(scene).arrays().own


def test_a_frozen_frame_follows_the_scene_when_it_changes(mi):
    """A shape moved and an emitter made brighter through ``mi.traverse`` and
    ``params.update()`` between frozen frames: each frozen frame equals bitwise a traced
    render of the scene as it is then, and the second change replays (no recording).
    The changes show in the traced images, so a frame stuck on the old scene fails."""
    from renderers.methods.base import render_stage
    from renderers.methods.pt import PTParams, path_integrator
    from renderers.scenes import load_scene
    from renderers.timing import StageTimer

    gc.collect()
    loaded = load_scene("many-lights", 8)
    scene = loaded.scene
    with frozen_frames(True):
        integrator = path_integrator(PTParams(max_depth=3))
        frame = render_stage(loaded, integrator, 1)

    def frozen_and_traced(seed: int) -> tuple[np.ndarray, np.ndarray]:
        frozen = np.asarray(frame(0, seed, StageTimer()))
        traced = np.asarray(mi.render(scene, integrator=integrator, spp=1, seed=seed))
        return frozen, traced

    for seed in range(4):   # settle the recordings
        frozen, traced = frozen_and_traced(seed)
    np.testing.assert_array_equal(frozen, traced)
    before = traced

    params = mi.traverse(scene)
    shape = next(k for k in params.keys() if k.endswith("vertex_positions"))
    light = next(k for k in params.keys() if k.endswith("emitter.radiance.value"))
    recordings = []
    for _ in range(2):
        params[shape] = params[shape] + 0.05
        params[light] = params[light] * 4
        params.update()
        frozen, traced = frozen_and_traced(3)
        assert not np.array_equal(traced, before)
        np.testing.assert_array_equal(frozen, traced)
        before = traced
        recordings.append(frame.recordings())
    assert recordings[1] == recordings[0]


def test_a_scene_without_emitters_renders_frozen_as_traced(mi):
    """Its emitter pointer array has width 0 and is no Dr.Jit variable (index 0): handed
    to a frozen call's input walk, Dr.Jit aborted the process ("jit_var(r0): unknown
    variable!"), which the suite's first run of a scene without emitters showed. The
    empty arrays are left out; the frozen frame equals the traced render."""
    import drjit as dr

    from renderers.frozen import Frozen

    gc.collect()
    scene = mi.load_dict({"type": "scene", "shape": {
                              "type": "rectangle",
                              "to_world": mi.ScalarTransform4f().translate([0, 0, 2])},
                          "integrator": {"type": "depth"},   # not black without light
                          "sensor": {"type": "perspective", "film": {
                              "type": "hdrfilm", "width": 4, "height": 4}}})
    assert dr.width(scene.emitters_dr()) == 0 and scene.emitters_dr().index == 0
    call = Frozen(lambda scene, seed: mi.render(scene, spp=1, seed=seed))
    for seed in range(4):
        frozen = np.asarray(call(scene, mi.UInt32(seed)))
    traced = np.asarray(mi.render(scene, spp=1, seed=3))
    assert traced.max() > 0
    np.testing.assert_array_equal(frozen, traced)
    del scene, call
    gc.collect()


#: A process of its own (the registry holds every emitter alive in a process, and this
#: suite's fixtures hold other scenes): many-lights (area lights only) rendered by a
#: frozen call, beside an environment emitter too, and with the registry's answer
#: planted. Each frozen render is compared bitwise with a traced one.
EMITTERS_SCRIPT = """
import json
import numpy as np
from renderers.backend import init_backend
mi = init_backend()
import renderers.frozen as frozen
from renderers.scenes import load_scene

scene = load_scene("many-lights", 4).scene
layout = frozen.SceneLayout(scene)
integrator = mi.load_dict({"type": "path", "max_depth": 3})

def frozen_call():
    return frozen.Frozen(lambda scene, seed: mi.render(scene, integrator=integrator, spp=1,
                                                        seed=seed))

def frozen_and_traced(call):
    for seed in range(4):
        image = np.asarray(call(scene, mi.UInt32(seed)))
    return image, np.asarray(mi.render(scene, integrator=integrator, spp=1, seed=3))

def frozen_is_traced(call):
    image, traced = frozen_and_traced(call)
    return bool(np.array_equal(image, traced))

call = frozen_call()
image, before = frozen_and_traced(call)
seen = {"in_shapes": layout.emitters_in_shapes, "walked_alone": layout.emitters_walked(),
        "alone": bool(np.array_equal(image, before))}
params = mi.traverse(scene)   # the emitters changed: their shapes' walk meets the values
for light in [k for k in params.keys() if k.endswith("emitter.radiance.value")]:
    params[light] = params[light] * 4
params.update()
image, after = frozen_and_traced(call)   # replayed
seen.update(changed=bool(np.array_equal(image, after)),
            moved=not np.array_equal(before, after))
environment = mi.load_dict({"type": "constant"})   # an emitter no shape holds
seen.update(walked_beside=layout.emitters_walked(), beside=frozen_is_traced(frozen_call()))
frozen.registered_emitters = lambda: layout.emitter_addresses   # planted
try:
    seen["planted"] = frozen_is_traced(frozen_call())
except RuntimeError as error:
    seen["planted"] = "refused: " + str(error)[:80]
print(json.dumps(seen))
"""


def test_the_emitters_domain_is_walked_unless_the_shapes_cover_every_emitter():
    """A scene whose emitters are all area lights, alone in its process, hands its
    emitters over as a plain array (its shapes' walk meets their variables): the frozen
    frame equals the traced render, and still does after the emitters changed. Beside an emitter no shape holds, which a call over
    the emitters traces too, the emitters are walked again, and the frame still equals
    the traced one; planted, the registry's answer ignoring that emitter: Dr.Jit refuses
    the recording. About 4 s: a process of its own (see EMITTERS_SCRIPT)."""
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-c", EMITTERS_SCRIPT], cwd=root,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["in_shapes"] and not seen["walked_alone"] and seen["alone"] is True
    assert seen["changed"] is True and seen["moved"]
    assert seen["walked_beside"] and seen["beside"] is True
    assert str(seen["planted"]).startswith("refused"), seen["planted"]
