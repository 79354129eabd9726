"""Animations: the spec's validation, the player's scene updates, frozen frames that
follow them, and PT unbiased against each frame's own reference."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from jobs.protocol.spec import RenderSpec
from metrics.statistics import agreement_test
from renderers.frozen import frozen_frames
from renderers.methods import get_method
from renderers.methods.base import FrameHooks
from renderers.reference import ReferenceSettings, render_reference
from renderers.scenes import SceneError, load_scene
from renderers.scenes.animated import animated_names, get_animated
from renderers.scenes.animation import Animation
from renderers.scenes.loader import animated

RES = 8
#: The small box moves 0.5 forward and turns 90 degrees in one frame: a pose change
#: visible at 8x8, so that a frame rendered one pose late is caught.
FAST_MOTION = {"shapes": [{"shape": "small-box", "pivot": (0.335, -0.7, 0.38), "keys": [
    {"frame": 0}, {"frame": 1, "translate": (-0.3, 0.0, 0.5), "angle_deg": 90.0}]}]}


@pytest.mark.parametrize(("spec", "message"), [
    ({}, "needs camera keys, shape motions or emitter changes"),
    ({"camera": [{"frame": 3, "position": (0, 0, 1), "target": (0, 0, 0)},
                 {"frame": 1, "position": (0, 0, 2), "target": (0, 0, 0)}]},
     "strictly increasing frames"),
    ({"camera": [{"frame": 0, "position": (0, 0, 1), "target": (0, 0, 1)}]},
     "target equals position"),
    ({"camera": [{"frame": 0, "position": (0, 0, 1), "target": (0, 0, 0), "up": (0, 0, 1)}]},
     "up is parallel"),
    ({"shapes": [{"shape": "box", "axis": (0, 0, 0), "keys": [{"frame": 0}]}]},
     "axis must not be zero"),
    ({"emitters": [{"emitter": "light", "frame": 2, "scale": -1.0}]}, "greater than or equal"),
    ({"emitters": [{"emitter": "light", "frame": 2, "scale": float("nan")}]}, "finite"),
    ({"shapes": [{"shape": "box", "keys": [{"frame": 0}]}] * 2}, "two motions"),
])
def test_an_invalid_animation_is_refused_naming_what_is_wrong(spec, message):
    with pytest.raises(ValidationError, match=message):
        Animation.model_validate(spec)
    # A render spec carrying it is refused the same way (REST answers 422).
    with pytest.raises(ValidationError, match=message):
        RenderSpec.model_validate({"scene": "cornell-box", "animation": spec})


def test_an_animation_naming_what_the_scene_lacks_is_refused_with_what_it_has(mi):
    scene = load_scene("cornell-box", 4)
    with pytest.raises(SceneError, match="no shape 'chair'.*small-box"):
        animated(scene, Animation.model_validate(
            {"shapes": [{"shape": "chair", "keys": [{"frame": 0}]}]}))
    with pytest.raises(SceneError, match="no emitter 'floor'.*light"):
        animated(scene, Animation.model_validate(
            {"emitters": [{"emitter": "floor", "frame": 1, "scale": 0.0}]}))


def test_states_are_interpolated_held_and_stepped():
    animation = Animation.model_validate({"shapes": [{"shape": "box", "keys": [
        {"frame": 2}, {"frame": 6, "translate": (4.0, 0.0, 0.0)},
        {"frame": 9, "translate": (0.0, 0.0, 0.0), "step": True}]}],
        "emitters": [{"emitter": "light", "frame": 4, "scale": 0.0}]})
    moves = [animation.state(f).shapes["box"][0][0] for f in range(11)]
    assert moves == [0, 0, 0, 1, 2, 3, 4, 4, 4, 0, 0]
    assert [animation.state(f).emitters["light"] for f in (3, 4)] == [1.0, 0.0]
    assert animation.change_frames() == [4, 9]
    # Frames showing one state share a key (and a reference), others do not.
    keys = [animation.state_key(f) for f in range(11)]
    assert keys[0] == keys[2] and keys[6] == keys[8] and len(set(keys)) == 6


def _frames(scene, frames, spp, seed, *, frozen=True, late_after=None):
    """PT's frames of the animated ``scene``; from frame ``late_after`` on each frame is
    shown one state late (the planted defect)."""
    player = scene.player
    method = get_method("pt")

    def show(index):
        player.apply(index - 1 if late_after is not None and index >= late_after else index)

    player.apply(0)
    with frozen_frames(frozen):
        output = method.render(scene, method.params(), seed_parts=("animation-test", seed),
                               spp=spp, frames=frames,
                               hooks=FrameHooks(keep_frames=True, before_frame=show))
    return output


def test_a_frozen_frame_follows_moved_shapes_and_changed_radiance(mi):
    """Frozen frames replay recordings on the updated scene values: the same seeds give
    the traced frames' images after a shape moved (frame 2) and the light tripled (3)."""
    animation = Animation.model_validate({
        "shapes": [{"shape": "small-box", "keys": [
            {"frame": 0}, {"frame": 2, "translate": (-0.3, 0.0, 0.3), "step": True}]}],
        "emitters": [{"emitter": "light", "frame": 3, "scale": 3.0}]})
    scene = animated(load_scene("cornell-box", RES), animation)
    frozen = _frames(scene, 4, 4, seed=1)
    assert frozen.timings["frozen"] is not None
    traced = _frames(scene, 4, 4, seed=1, frozen=False)
    for a, b in zip(frozen.frames, traced.frames, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    # Planted: frames shown one state late differ from the traced ones at each change.
    late = _frames(scene, 4, 4, seed=1, late_after=2)
    for index in (2, 3):
        assert not np.allclose(late.frames[index], traced.frames[index], rtol=1e-3)


SEEDS, SPP = 4, 32


def _reference(scene, frame):
    scene.player.apply(frame)
    image = render_reference(scene.scene, ReferenceSettings(spp=1024, spp_per_pass=64),
                             seed_parts=("animation-reference", frame))
    return image.mean.astype(np.float64), image.variance.astype(np.float64)


def _seed_moments(outputs, frame):
    images = np.stack([output.frames[frame] for output in outputs]).astype(np.float64)
    return images.mean(axis=0), images.var(axis=0, ddof=1) / len(outputs)


def test_pt_is_unbiased_against_each_frames_reference_on_a_moving_object(mi):
    """Per-pixel Sidak z-test and aggregate chi2 (agreement_test) of every frame of K
    seeds against that frame's reference; planted: frames rendered with the previous
    frame's transform are rejected."""
    scene = animated(load_scene("cornell-box", RES), Animation.model_validate(FAST_MOTION))
    # Traced frames: a frozen loop's warm-up (until its recordings settle) would cost
    # most of the test; that frozen frames give the traced images is tested above.
    outputs = [_frames(scene, 2, SPP, seed, frozen=False) for seed in range(SEEDS)]
    late = [_frames(scene, 2, SPP, seed, frozen=False, late_after=1) for seed in range(SEEDS)]
    for frame in range(2):
        reference = _reference(scene, frame)
        result = agreement_test(*_seed_moments(outputs, frame), *reference, dof=SEEDS - 1)
        assert result.passed, f"frame {frame}: {result.summary()}"
        if frame:
            planted = agreement_test(*_seed_moments(late, frame), *reference, dof=SEEDS - 1)
            assert not planted.passed, f"late frame {frame} passed: {planted.summary()}"


def test_the_builtin_animated_scenes_load_and_change(mi):
    for name in animated_names():
        scene = load_scene(name, 4)
        base = load_scene(get_animated(name).base, 4)
        assert scene.animation is not None and scene.fingerprint != base.fingerprint
        keys = {scene.animation.state_key(f) for f in range(16)}
        assert len(keys) > 1, name
