"""Every method's output under fixed seeds, held against a stored fingerprint per
estimator version: a change of output without a version bump fails and names the
method.

A fingerprint is a tiny render (8x8, 1 spp, 2 frames, paths of at most 4 vertices,
``PRETRAIN`` training frames first for the methods that train) of the first of
``SCENES`` the method applies to, stored in ``golden/fingerprints.json`` with the
method's version. A render matches when no pixel value moves by more than
``TOLERANCE`` times the image's mean value. Why that tolerance: Dr.Jit's LLVM backend
vectorises for the CPU it runs on (8 lanes with AVX2, 16 with AVX-512), which changes
the order of float sums in training and reductions; measured against renders from
another CPU, the same code moved values by at most 8.2e-5 (2.2e-5 relative on
average; tests/renderers/test_termination.py), and two runs on one CPU give the same
bits (measured: every method, two runs). `grid-cache` sums with float atomics, whose
order may vary between runs on more cores (five runs here gave the same bits): it is
allowed ``NOISY``'s tolerance. The planted tests below show the tolerance is tight
enough: emitters 1 % brighter fail every method, and a cache's learning rate 1 %
higher fails every method that trains one.

After an intended change of a method's output, bump its ``version`` (the Method at
the bottom of its module) and write its fingerprint anew::

    NIRC_BENCH_WRITE_FINGERPRINTS=1 .venv/bin/python -m pytest tests/renderers/test_fingerprints.py
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from renderers.methods import METHODS, get_method, parse_params
from tests.support.untimed import UNTIMED

GOLDEN = Path(__file__).parent / "golden" / "fingerprints.json"
WRITE = os.environ.get("NIRC_BENCH_WRITE_FINGERPRINTS") == "1"

RES, FRAMES, PRETRAIN, DEPTH = 8, 2, 4, 4
#: The scenes tried in order for a method (the first it applies to).
SCENES = ("many-lights", "sky")
#: Largest move of one pixel value, relative to the image's mean value (module doc).
TOLERANCE = 1e-3
#: Methods whose runs may differ (float atomics), and the tolerance they are allowed.
NOISY = {"grid-cache": 1e-2}


def _scene(method: Any):
    from renderers.scenes import load_scene

    for name in SCENES:
        scene = load_scene(name, RES)
        if method.applies_to(scene.features)[0]:
            return name, scene
    raise AssertionError(f"no fingerprint scene for {method.name}")


def _params(name: str, **changes: Any) -> Any:
    fields = get_method(name).params.model_fields
    wanted = {"prefill_frames": 2, "pretrain_frames": PRETRAIN, **changes}
    depth = fields["max_depth"].default if "max_depth" in fields else None
    if depth is not None and (depth == -1 or depth > DEPTH):
        wanted["max_depth"] = DEPTH   # paths of at most DEPTH vertices where longer
    return parse_params(name, {key: value for key, value in wanted.items() if key in fields})


def fingerprint(name: str, params: Any = None, scene: Any = None) -> np.ndarray:
    """The method's fingerprint render (module doc), as a (RES, RES, 3) float array."""
    method = get_method(name)
    scene = _scene(method)[1] if scene is None else scene
    output = method.render(scene, _params(name) if params is None else params,
                           seed_parts=("fingerprint", name), spp=1, frames=FRAMES,
                           hooks=UNTIMED)
    return np.asarray(output.accumulated, dtype=np.float64)


def deviation(image: np.ndarray, golden: np.ndarray) -> float:
    """The largest move of a pixel value, relative to the golden image's mean value."""
    return float(np.abs(image - golden).max() / max(np.abs(golden).mean(), 1e-12))


def _stored() -> dict[str, Any]:
    return json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}


@pytest.fixture(scope="module")
def stored(mi) -> dict[str, Any]:
    return _stored()


@pytest.mark.parametrize("name", list(METHODS))
def test_a_method_renders_its_fingerprint(stored, name):
    method = get_method(name)
    scene_name, scene = _scene(method)
    image = fingerprint(name, scene=scene)
    assert np.isfinite(image).all()
    if WRITE:
        entries = _stored()
        entries[name] = {"version": method.version, "scene": scene_name,
                         "image": np.round(image, 9).tolist()}
        GOLDEN.write_text(json.dumps(entries, indent=1, sort_keys=True) + "\n")
        return
    entry = stored.get(name)
    assert entry is not None, f"{name} has no fingerprint: write it (module doc)"
    assert entry["version"] == method.version, (
        f"{name} is version {method.version} but its fingerprint is of version "
        f"{entry['version']}: write it anew (module doc)")
    moved = deviation(image, np.asarray(entry["image"]))
    assert moved <= NOISY.get(name, TOLERANCE), (
        f"{name}'s output changed (a pixel moved by {moved:.2e} of the image mean) with "
        f"its estimator version unchanged ({method.version}): bump the version if the "
        f"change is intended")


def _brighter(scene: Any, factor: float) -> None:
    """Scale every emitter of ``scene`` by ``factor`` (area lights' radiance, an
    environment map's scale) through Mitsuba's scene parameters."""
    import mitsuba as mi

    params = mi.traverse(scene.scene)
    keys = [key for key in params.keys()
            if key.endswith(("radiance.value", "intensity.value", "irradiance.value"))
            or (key.endswith(".scale") and key[:-len(".scale")] + ".data" in params)]
    assert keys, "no emitter parameter to scale"
    for key in keys:
        params[key] = params[key] * factor
    params.update()


#: The planted tests compare with the stored fingerprints: not while they are written.
planted = pytest.mark.skipif(WRITE, reason="writing fingerprints")


@planted
@pytest.mark.parametrize("name", list(METHODS))
def test_emitters_one_percent_brighter_fail_the_fingerprint(stored, name):
    """Planted: the same render with every emitter 1 % brighter is outside the
    tolerance (by more than twice), for every method."""
    method = get_method(name)
    scene = _scene(method)[1]
    _brighter(scene, 1.01)
    moved = deviation(fingerprint(name, scene=scene), np.asarray(stored[name]["image"]))
    assert moved > 2 * NOISY.get(name, TOLERANCE)


#: Methods that train a neural cache (a ``cache`` parameter with an optimizer).
NEURAL = [name for name, method in METHODS.items()
          if "cache" in method.params.model_fields and name != "grid-cache"]


@planted
@pytest.mark.parametrize("name", NEURAL)
def test_a_learning_rate_one_percent_higher_fails_the_fingerprint(stored, name):
    """Planted: the cache's learning rate 1 % higher (the preset's, read from the
    method's own cache config) is outside the tolerance."""
    params = _params(name)
    presets = params.cache_presets()
    config = presets["cache"](**params.cache) if "cache" in presets else None
    assert config is not None and config.optimizer.lr > 0
    changed = _params(name, cache={**params.cache, "optimizer": {
        **config.optimizer.model_dump(), "lr": config.optimizer.lr * 1.01}})
    moved = deviation(fingerprint(name, changed), np.asarray(stored[name]["image"]))
    assert moved > 2 * TOLERANCE, f"{name}: moved only {moved:.2e}"
