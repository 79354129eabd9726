"""Light selection tables follow an animation: after lights switch off (many-lights-switch,
frame 6) and on again (frame 12), the power-based selectors' pmfs are those of the
scene as it is then (planted: tables kept from load time are detected)."""

from __future__ import annotations

import numpy as np
import pytest

import renderers.frozen
from renderers.methods.pt import PTParams, path_integrator
from renderers.scenes import load_scene

SWITCHED = {f"light-{index:02d}" for index in range(8)}


@pytest.mark.parametrize("planted", [False, True])
@pytest.mark.parametrize("kind", ["PowerLightSampler", "SpatialLightSampler"])
def test_a_switched_off_lights_pmf_follows_the_switch(mi, monkeypatch, kind, planted):
    from renderers.integrators import lights

    if planted:   # the scene's updates never reach the selector: load-time tables
        monkeypatch.setattr(renderers.frozen, "scene_generation", lambda scene: 0)
    scene = load_scene("many-lights-switch", 4)
    integrator = path_integrator(PTParams())
    integrator.light_sampler_type = getattr(lights, kind)
    emitters = scene.scene.emitters()
    off = np.array([emitter.get_shape().id() in SWITCHED for emitter in emitters])
    assert off.sum() == len(SWITCHED) and len(emitters) == 32

    def pmf() -> np.ndarray:
        powers = integrator.light_sampler(scene.scene).powers
        return powers / powers.sum()

    on = pmf()
    scene.player.apply(6)
    switched_off = pmf()
    scene.player.apply(12)
    switched_on = pmf()
    # Off: the floor (POWER_FLOOR of the mean power), the others share the rest.
    followed = (np.all(switched_off[off] < 1e-2 * on[off])
                and np.allclose(switched_off[~off] / switched_off[~off].sum(),
                                on[~off] / on[~off].sum())
                and np.allclose(switched_on, on))
    assert followed != planted, (on, switched_off)
