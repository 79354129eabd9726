"""The `grid-cache` method and its variance-trading policies (renderers/methods/grid_cache.py,
renderers/integrators/grid_cache.py, renderers/integrators/termination/var_bound.py,
mse_min.py, area_spread.py; docs/variance_trading.md).

The renderer's decisions are the discrete model's formulas (checked here on Dr.Jit
arrays against the model's own rules); the blend of Eq. 5 is checked pixel by pixel
with common random numbers, and the planted wrong blends fail that check; on the
Cornell box (diffuse) with jitter off the variance of `var-bound` renders stays at the
threshold, bias falls and path length grows with it, and a marginal moment that pairs
a sample with itself breaks the bound."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from renderers.methods import MethodError, parse_params
from renderers.termination_model import (
    EXAMPLE_BIASES,
    MSEMinimizing,
    PathState,
    binary_tree,
    mse_min_terminates,
    variance_bound_weight,
    variance_bounding,
)

RES = 16
PREFILL = 24


# ---- The decisions are the model's ------------------------------------------------

def _states():
    """Every node of the model's trees with a spread of prefix weights and path variances."""
    for tree in (binary_tree(3), binary_tree(3, biases={k: v for k, v in EXAMPLE_BIASES.items()
                                                         if len(k) < 3})):
        for node, g, s in itertools.product(tree.nodes(), (0.5, 1.0, 4.5),
                                            (0.0, 0.01, 0.3, 2.0)):
            if not node.is_leaf:
                yield PathState(node, g, s)


def test_the_renderers_decisions_are_the_discrete_models(mi):
    """The policies call variance_bound_weight and mse_min_terminates on one lane per path;
    on Dr.Jit arrays they decide as the model's rules decide on floats (the rules' own
    tests, test_termination_model.py, cover their behaviour)."""
    states = list(_states())
    g = mi.Float([s.prefix_weight for s in states])
    path_variance = mi.Float([s.path_variance for s in states])
    local = mi.Float([s.prefixed_local_variance for s in states])
    for threshold in (0.05, 0.5, 3.0):
        rule = variance_bounding(threshold)
        expected = np.array([rule(s) for s in states])
        got = np.asarray(variance_bound_weight(path_variance, local, threshold))
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    bias2 = mi.Float([s.node.local_bias ** 2 for s in states])
    deferred = mi.Float([s.node.deferred_bias for s in states])
    decided = []
    for samples in (1.0, 10.0, 1000.0):
        rule = MSEMinimizing(samples)
        expected = np.array([rule(s) == 0.0 for s in states])
        got = np.asarray(mse_min_terminates(path_variance, local, g * g, bias2, deferred,
                                            samples, rule.margin, rule.clamp))
        assert (got == expected).mean() > 0.99          # float32 ties aside
        decided += list(expected)
    assert any(decided) and not all(decided)


def test_parameters_are_typed_and_refused_in_the_users_terms():
    params = parse_params("grid-cache", {"termination": "mse-min",
                                         "termination_params": {"samples": 10}})
    assert params.termination_policy().params.samples == 10
    with pytest.raises(MethodError, match="threshold"):
        parse_params("grid-cache", {"termination_params": {"threshold": -1}})
    with pytest.raises(MethodError, match="termination"):
        parse_params("grid-cache", {"termination": "bth"})   # NIRC's, not the grid's
    with pytest.raises(MethodError, match="cache: unknown cache config field"):
        parse_params("grid-cache", {"cache": {"cells": 3}})
    dumped = json.loads(params.model_dump_json())
    assert dumped["rr_survival"] == 0.9 and dumped["prefill_frames"] >= 0


# ---- Renders -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def filled(mi):
    """The Cornell box (diffuse) with a grid pre-filled for PREFILL passes, jitter off."""
    from renderers.methods.grid_cache import build, propagate
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", RES)
    assert not (scene.features.has_glossy or scene.features.has_delta)
    params = parse_params("grid-cache", {"cache": {"jitter": False}})
    integrator, updater, grid = build(scene, params, 11)
    for index in range(PREFILL):
        propagate(scene, updater, grid, params, index)
    return scene, params, integrator, updater, grid


class _FixedBlend:
    """A test policy: weight ``alpha`` at the first vertex, 0 (end) at the second."""

    def __init__(self, alpha: float) -> None:
        self.alpha = alpha

    def path_state(self) -> dict:
        return {}

    def continuation(self, query):
        import drjit as dr
        import mitsuba as mi

        depth = query.vertex.depth
        return dr.select(depth == 0, mi.Float(self.alpha),
                         dr.select(depth == 1, 0.0, 1.0)), query.state


def _render(mi, scene, integrator, seed, spp=1):
    image = np.asarray(mi.render(scene.scene, integrator=integrator, spp=spp, seed=seed))
    return image[..., :3], image[..., 3:]


def _blend_error(mi, filled, blend=None) -> float:
    """Largest deviation, relative to the image's scale, from Eq. 5 pixel by pixel:
    img(a) = (1 - a) img(0) + a img(1) with common random numbers."""
    scene, _params, integrator, _updater, _grid = filled
    cls = type(integrator)
    saved = cls.__dict__["blend"]
    if blend is not None:
        cls.blend = staticmethod(blend)
    try:
        images = {}
        for alpha in (0.0, 0.3, 1.0):
            integrator.policy = _FixedBlend(alpha)
            images[alpha] = _render(mi, scene, integrator, seed=3, spp=4)[0]
    finally:
        cls.blend = saved
    expected = 0.7 * images[0.0] + 0.3 * images[1.0]
    return float(np.abs(images[0.3] - expected).max() / np.abs(expected).mean())


def test_the_blend_is_eq5_and_planted_blends_are_caught(mi, filled):
    """Blending at the first vertex with weight a gives, pixel by pixel, a times the image
    that goes one segment further (its direct light and the cache at the next vertex)
    plus 1 - a times the image that ends at the first vertex (Eq. 5). A wrong sign of
    the blend, and a blend whose weight reaches the next vertex's cache but not the
    direct light of the segment, both break it by far more than float rounding."""
    assert _blend_error(mi, filled) < 1e-3
    assert _blend_error(mi, filled, lambda a: (1.0 + a, a, 1.0)) > 0.05
    assert _blend_error(mi, filled, lambda a: (1.0 - a, 1.0, a)) > 0.05



class _SecondVisit:
    """A test policy that counts the vertices it is asked at in its own path state
    (``path_state``) and ends the path at the second."""

    def path_state(self) -> dict:
        import mitsuba as mi

        return {"visits": mi.Float(0.0)}

    def continuation(self, query):
        import drjit as dr

        own = query.state.policy_state
        own["visits"] = dr.select(query.vertex.active, own["visits"] + 1.0, own["visits"])
        return dr.select(own["visits"] >= 2.0, 0.0, 1.0), query.state


def _cache_depths(mi, filled):
    scene, _params, integrator, _updater, _grid = filled
    integrator.policy = _SecondVisit()
    return _render(mi, scene, integrator, seed=7)[1][..., 1]


def test_the_policys_own_state_is_carried_along_the_path(mi, filled, monkeypatch):
    """A policy's declared path state reaches the next vertex: counting its own visits,
    it ends paths at the second vertex (cache_depth 2, or later where the second had
    no record), never at the first. Planted: an integrator that hands the policy a fresh
    state at every vertex never ends a path (cache_depth 0 everywhere)."""
    depths = _cache_depths(mi, filled)
    assert not (depths == 1).any()
    assert (depths == 2).mean() > 0.5, np.unique(depths, return_counts=True)

    from renderers.integrators.grid_cache import GridCacheIntegrator

    real = GridCacheIntegrator.vertex_terms

    def forgetting(self, vertex, state):
        state.policy_state = self.policy.path_state()
        return real(self, vertex, state)

    monkeypatch.setattr(GridCacheIntegrator, "vertex_terms", forgetting)
    assert not _cache_depths(mi, filled).any()

def _frames(mi, filled, policy, frames, seed=100):
    """Per-frame luminance images (grid frozen: no propagation between them) and the mean
    paper path length."""
    scene, _params, integrator, _updater, _grid = filled
    integrator.policy = policy
    lum, lengths = [], []
    for frame in range(frames):
        rgb, aovs = _render(mi, scene, integrator, seed=seed + frame)
        lum.append(rgb @ np.array([0.2126, 0.7152, 0.0722]))
        lengths.append(aovs[..., 3].mean())
    return np.array(lum), float(np.mean(lengths))


def _var_bound(threshold):
    from renderers.integrators.termination import make_policy, policy_params
    from renderers.methods.grid_cache import GridCacheParams

    settings = GridCacheParams().termination_settings()
    return make_policy(policy_params("var-bound", threshold=threshold), settings)


FRAMES = 96
THRESHOLDS = (1e-4, 1e-3, 1e-2, 1e-1)


@pytest.fixture(scope="module")
def sweep(mi, filled):
    """var-bound at each threshold and at t = 0 (every path ends at its first hit: the
    variance of the pixel footprint alone), and a path-traced reference."""
    from renderers.methods.pt import PTParams, path_integrator

    scene = filled[0]
    results = {t: _frames(mi, filled, _var_bound(t), FRAMES) for t in (0.0, *THRESHOLDS)}
    pt = path_integrator(PTParams())
    reference = np.asarray(mi.render(scene.scene, integrator=pt, spp=2048, seed=9))[..., :3]
    return results, reference @ np.array([0.2126, 0.7152, 0.0722])


def _smooth_pixels(results) -> np.ndarray:
    """The pixels whose footprint variance (the t = 0 frames') is below its upper
    quartile: the light's edge and the corners, where where a first hit falls in the
    pixel decides everything, would drown the variance under test in their own."""
    footprint = results[0.0][0].var(axis=0, ddof=1)
    return footprint < np.quantile(footprint, 0.75)


#: The threshold the bound is asserted at: below it the footprint term dominates (1e-4),
#: above it paths reach the end of the scene's light and the variance detaches (1e-2).
BOUNDED = 1e-3


def _excess_over_the_bound(results, frames: np.ndarray, t: float) -> float:
    """How far, in units of t, the mean per-pixel variance of ``frames`` above the
    footprint's lies beyond the tolerance 1.6 t + 4 standard errors (> 0: broken)."""
    smooth = _smooth_pixels(results)
    footprint = results[0.0][0].var(axis=0, ddof=1)[smooth]
    per_pixel = frames.var(axis=0, ddof=1)[smooth]
    excess = per_pixel.mean() - footprint.mean()
    se = np.sqrt((per_pixel.var() + footprint.var()) / per_pixel.size)
    print(f"t={t:g}: variance {per_pixel.mean():.4g} footprint {footprint.mean():.4g} "
          f"excess/t {excess / t:.3f}")
    return (excess - 1.6 * t - 4 * se) / t


def test_var_bound_keeps_the_variance_at_the_threshold(mi, filled, sweep, monkeypatch):
    """Over the smooth pixels, the mean per-pixel variance of 1-spp var-bound frames less
    that of the t = 0 frames (every path ends at its first hit: the pixel footprint, P_0
    of Eq. 1, which no record estimates) stays at the threshold t (Eq. 2 with the blend
    of Eq. 5 brings every path's sum to t or below), asserted at t = 1e-3, where the
    bound binds (at 1e-2 paths reach the end of the scene's light and the variance
    detaches below t). Planted: a policy that reads a quarter of each record's local
    variance spends four times the budget and breaks the bound.

    Tolerance: 1.6 t plus 4 standard errors. Named sources, measured here at 1.4 t:
    (1) the footprint term is not additive — a blended pixel is (1 - a) rc(x_1) +
    a E[Y | x_1], whose spread over the pixel adds 2 a Cov(rc(x_1), E[Y | x_1] - rc(x_1)),
    of order sqrt(t) rather than t (so t = 1e-4, where it dominates, is not asserted);
    (2) the local variances are noisy estimates (8 samples per vertex, a few dozen
    updates per record) and a record's average variance stands for every point of its
    cell; (3) a blended path whose next vertex has no record yet goes on as PT
    (unbiased, but its variance is not bounded), as do paths through unexplored cells;
    (4) roulette after the fifth vertex."""
    from renderers.integrators.termination import var_bound

    results, _reference = sweep
    assert _excess_over_the_bound(results, results[BOUNDED][0], BOUNDED) <= 0

    real = var_bound.prefixed_local_variance
    monkeypatch.setattr(var_bound, "prefixed_local_variance",
                        lambda query, local: 0.25 * real(query, local))
    planted = _frames(mi, filled, _var_bound(BOUNDED), FRAMES)[0]
    assert _excess_over_the_bound(results, planted, BOUNDED) > 0


def test_var_bound_trades_bias_for_path_length(sweep):
    """As t grows, paths get longer (the paper's Fig. 7 right) and the noise-corrected
    squared bias against the path-traced reference, over the smooth pixels, falls
    (Fig. 7 left), from the smallest to the largest threshold."""
    results, reference = sweep
    smooth = _smooth_pixels(results)
    lengths = [results[t][1] for t in THRESHOLDS]
    bias2 = []
    for t in THRESHOLDS:
        frames = results[t][0]
        raw = (frames.mean(axis=0) - reference) ** 2 - frames.var(axis=0, ddof=1) / FRAMES
        bias2.append(float(raw[smooth].mean()))
    print("lengths", lengths, "bias2", bias2)
    assert all(a < b for a, b in itertools.pairwise(lengths)), lengths
    assert bias2[-1] < 0.5 * bias2[0], bias2


def test_the_local_variance_is_the_within_vertex_variance(mi, filled, monkeypatch):
    """On the update pass's own samples, a fresh record's average variance E[Y^2] -
    E[E[Y|y]^2] equals the mean over its vertices of the unbiased sample variance of
    their K samples (algebraically, with the U-statistic of distinct pairs). Planted:
    the marginal moment pairing each sample with itself makes it (K - 1) / K of that,
    which var-bound would read as variance it may spend (with K = 8, 12 % more)."""
    import drjit as dr

    from renderers.caches import moment_grid
    from renderers.caches.moment_grid import MomentGrid
    from renderers.integrators.grid_update import update_grid

    scene, params, _integrator, updater, grid = filled
    k = grid.config.samples_per_vertex
    captured = {}
    original = MomentGrid.accumulate

    def capture(self, slot, samples, active, *rest):
        captured.update(slot=np.asarray(slot), samples=np.asarray(mi.luminance(samples)),
                        active=np.asarray(active))
        return original(self, slot, samples, active, *rest)

    monkeypatch.setattr(MomentGrid, "accumulate", capture)
    update_grid(scene.scene, updater, 77, 0.0)
    samples = captured["samples"].reshape(-1, k)
    within = samples.var(axis=1, ddof=1)
    slot = captured["slot"]
    active = captured["active"]

    def grid_variance(marginal):
        monkeypatch.setattr(moment_grid, "marginal_second_moment", marginal)
        fresh = MomentGrid(grid.config)
        # Luminances as grey colours: the luminance of a grey is the grey.
        grey = mi.Float(captured["samples"])
        original(fresh, mi.UInt32(slot), mi.Color3f(grey, grey, grey), mi.Bool(active))
        return np.asarray(fresh.second) - np.asarray(fresh.marginal)

    expected = np.zeros(grid.config.table_size)
    counts = np.zeros(grid.config.table_size)
    np.add.at(expected, slot[active], within[active])
    np.add.at(counts, slot[active], 1)
    used = counts > 0
    expected = expected[used] / counts[used]
    correct = grid_variance(moment_grid.marginal_second_moment)[used]
    planted = grid_variance(lambda sum_y, sum_y2, kk: dr.square(sum_y / kk))[used]
    scale = expected.mean()
    assert np.abs(correct - expected).max() < 1e-3 * scale + 1e-6
    assert np.abs(planted - expected * (k - 1) / k).max() < 1e-3 * scale + 1e-6
    assert np.abs(planted - expected).mean() > 0.05 * scale




# ---- The frozen propagation pass ----------------------------------------------------

@pytest.fixture(scope="module")
def grid_states(mi):
    """(scene, [(representatives, the grid's arrays)]): cornell-box at 8x8 after passes
    that store every first hit, at three states whose representatives the frozen
    update pads to three different widths."""
    from renderers.methods.grid_cache import build, propagate
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 8)
    params = parse_params("grid-cache", {"max_depth": 3, "hit_store_probability": 0.3,
                                         "cache": {"primary_store_probability": 1.0}})
    _integrator, updater, grid = build(scene, params, 5)
    states = []
    for index in range(40):
        propagate(scene, updater, grid, params, index)
        vertices = len(grid.places())
        if not states or _width(vertices) != _width(states[-1][0]):
            states.append((vertices, grid.copied_arrays()))
        if len(states) == 3:
            return scene, states
    raise AssertionError(f"the representatives crossed too few widths: {states}")


def _width(vertices: int) -> int:
    from renderers.methods.grid_cache import Propagation

    return max(1 << (vertices - 1).bit_length(), Propagation.MIN_WIDTH)


def _passes(scene, states, params, frozen: bool, order) -> list[dict[str, np.ndarray]]:
    """One propagation (frozen or traced) over copies of the grid ``states`` in ``order``:
    the grid's arrays after each pass."""
    from renderers.methods.grid_cache import Propagation, build

    _integrator, updater, grid = build(scene, params, 5)
    propagation = Propagation(scene, updater, grid, params, frozen=frozen)
    results = []
    for at in order:
        grid.bind(states[at][1])
        grid.bind(grid.copied_arrays())   # a replay writes into the arrays it is handed
        propagation(100 + at)
        results.append({name: np.asarray(array) for name, array in grid.arrays().items()})
    if frozen:   # each state at its own width
        assert propagation.frozen and len(propagation.widths) == len(set(order))
    return results


def _differences(a, b) -> dict[str, float]:
    return {name: float(np.abs(a[name].astype(np.float64) - b[name]).max()) for name in a}


def _assert_same_records(a, b) -> None:
    """Keys, counts and representatives the same bits; moments within float32 rounding
    of the two kernels' arithmetic (their sums are order-free, moment_grid)."""
    moved = _differences(a, b)
    assert max(moved[name] for name in ("keys", "count", "bias_count", "vertices",
                                         "vertex_used")) == 0
    scale = np.abs(a["mean"]).max()
    assert max(moved[name] for name in ("mean", "second", "marginal", "bias",
                                        "deferred")) <= 1e-6 * scale


NO_INSERTIONS = {"max_depth": 3, "hit_store_probability": 0.0,
                 "cache": {"primary_store_probability": 0.0}}


def test_the_frozen_propagation_pass_gives_the_traced_records(grid_states, monkeypatch):
    """Without insertions, on grid states whose representatives the frozen pass pads to
    three different widths, called in turn so that recordings are replayed after others
    of other widths: the same records as the traced pass (_assert_same_records).
    Planted: the padding lanes left unmasked (they update the last representative's
    record again): its count differs."""
    from renderers.integrators import grid_update

    scene, states = grid_states
    assert all(vertices & (vertices - 1) for vertices, _ in states)   # padded lanes exist
    params = parse_params("grid-cache", NO_INSERTIONS)
    order = [0, 1, 2, 0, 2, 1]
    traced = _passes(scene, states, params, False, order)
    frozen = _passes(scene, states, params, True, order)
    for a, b in zip(traced, frozen, strict=True):
        _assert_same_records(a, b)

    original = grid_update.update_places

    def unmasked(scene, integrator, place, _vertices, seed, probability, history):
        import drjit as dr
        import mitsuba as mi

        original(scene, integrator, place, dr.opaque(mi.UInt32, len(place)), seed,
                 probability, history)

    monkeypatch.setattr(grid_update, "update_places", unmasked)
    planted = _passes(scene, states, params, True, [0])[0]
    assert _differences(traced[0], planted)["count"] > 0


def test_with_insertions_the_frozen_pass_grows_the_grid_as_the_traced_one(grid_states):
    """With insertions (first hits and the update's hits kept as representatives, racing
    for slots and places): the frozen and the traced pass leave the same records
    (_assert_same_records), more representatives than before."""
    scene, states = grid_states
    params = parse_params("grid-cache", {"max_depth": 3, "hit_store_probability": 0.3,
                                         "cache": {"primary_store_probability": 1.0}})
    order = [0, 1, 2]
    traced = _passes(scene, states, params, False, order)
    frozen = _passes(scene, states, params, True, order)
    for (before, _), a, b in zip(states, traced, frozen, strict=True):
        assert a["vertex_used"].sum() > before
        _assert_same_records(a, b)
