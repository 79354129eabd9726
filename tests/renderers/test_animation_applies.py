"""Methods whose per-scene state an animation's update does not refresh refuse the
animations that would make it stale, with the reason (docs/animation.md, "Per-scene
state of the methods"), and take the same scene static or animated otherwise."""

from __future__ import annotations

from renderers.methods import get_method
from renderers.scenes import load_scene
from renderers.scenes.animation import Animation
from renderers.scenes.loader import LoadedScene, animated

RES = 4
MOVE = {"keys": [{"frame": 0}, {"frame": 2, "translate": (0.1, 0.0, 0.0)}]}


def _moving(base: LoadedScene, shape: str) -> LoadedScene:
    return animated(base, Animation.model_validate({"shapes": [{"shape": shape, **MOVE}]}))


def test_the_grid_cache_refuses_moving_shapes_and_takes_a_light_change(mi):
    grid = get_method("grid-cache")
    refused, why = grid.applies_to(load_scene("door-sudden", RES).features)
    assert not refused and "cell edge is sized from the scene's extent" in why
    assert grid.applies_to(load_scene("cornell-box-sudden", RES).features) == (True, "")
    assert grid.applies_to(load_scene("cornell-box", RES).features) == (True, "")


def test_clustered_light_caches_refuse_moving_shapes_beyond_32_lights(mi):
    static = load_scene("many-lights-300", RES)
    moving = _moving(static, "light-000").features
    assert moving.animation_changes == ("shapes",)
    few = _moving(load_scene("many-lights", RES), "light-00")
    for name in ("nvc-lights", "restir-nvc"):
        method = get_method(name)
        refused, why = method.applies_to(moving)
        assert not refused and "clustered by position once at load time" in why, name
        # The same scene static, and 32 lights moving (one output per light), are taken.
        assert method.applies_to(static.features)[0], name
        assert method.applies_to(few.features)[0], name
