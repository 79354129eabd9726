"""The hashed-grid radiance cache with three moments (renderers/caches/moment_grid.py):
keys, the moments against their known values on synthetic samples (and a planted
estimator that pairs a sample with itself), stochastic interpolation, representatives."""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from scipy import stats

pytestmark = pytest.mark.usefixtures("mi")

CELL = 0.1


def grid(**overrides):
    from renderers.caches.grid_config import MomentGridConfig
    from renderers.caches.moment_grid import MomentGrid

    return MomentGrid(MomentGridConfig(**{"cell_size": CELL, "log2_table_size": 12,
                                          **overrides}))


def points(mi, array):
    return mi.Point3f(*(mi.Float(np.ascontiguousarray(array[:, i])) for i in range(3)))


def up(mi, n=1):
    return mi.Vector3f(0.0, 0.0, 1.0) if n == 1 else mi.Vector3f(
        dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.ones(mi.Float, n))


def test_a_key_finds_its_own_record_or_none(mi):
    """Every cell inserted is found again at its own slot; in a table too small for
    them, the cells that found no slot are misses, never another cell's record."""
    rng = np.random.default_rng(1)
    cells = rng.permutation(np.array(np.meshgrid(*[np.arange(12)] * 3)).reshape(3, -1).T)[:600]
    centres = (cells + 0.5) * CELL
    for log2, all_found in ((12, True), (8, False)):
        cache = grid(log2_table_size=log2)
        slot, found = cache.find(points(mi, centres), up(mi), True, insert=True)
        slot, found = np.asarray(slot), np.asarray(found)
        assert found.all() == all_found
        assert len(set(slot[found])) == found.sum()            # one record per cell
        again, found_again = cache.find(points(mi, centres), up(mi))
        assert (np.asarray(found_again) == found).all()
        assert (np.asarray(again)[found] == slot[found]).all()
        if not all_found:
            assert found.sum() == 256 and (~found).sum() == 600 - 256
    # The two sides of a wall are two records with normal bins, one without.
    for bins, records in ((True, 2), (False, 1)):
        cache = grid(normal_bins=bins)
        p = mi.Point3f([0.05, 0.05], [0.05, 0.05], [0.05, 0.05])
        slot, _ = cache.find(p, mi.Vector3f([0, 0], [0, 0], [1, -1]), True, insert=True)
        assert len(set(np.asarray(slot).tolist())) == records


def feed(mi, cache, means, sigmas, frames, rng, k):
    """``frames`` updates of every vertex (one row of ``means``/``sigmas`` per cell,
    one column per vertex of that cell): K samples Y = mean + sigma z, grey."""
    cells, per_cell = means.shape
    centres = (np.arange(cells)[:, None] + 0.5) * CELL * np.array([[1.0, 0.0, 0.0]])
    at = np.repeat(centres, per_cell, axis=0)
    slot, found = cache.find(points(mi, at), up(mi, len(at)), True, insert=True)
    assert dr.all(found)
    for _ in range(frames):
        y = (means.reshape(-1, 1) + sigmas.reshape(-1, 1)
             * rng.standard_normal((cells * per_cell, k))).ravel()
        grey = mi.Float(y)
        cache.accumulate(slot, mi.Color3f(grey, grey, grey), mi.Bool(True))
    return slot


@pytest.mark.parametrize("planted", [False, True], ids=["u-statistic", "self-pairs"])
def test_the_three_moments_estimate_variance_and_bias(mi, monkeypatch, planted):
    """200 cells, each 4 representatives drawn at random from points with E[Y|y] in
    {0.5, 1, 2, 4} (equally likely) and sd(Y|y) 2, K = 8, 30 updates: per cell the
    average local variance must estimate E[V[Y|y]] = 4 and the squared bias
    Var(E[Y|y]) = 1.8125 (t-tests across the independent cells; the bias is formed
    within each update from its distinct representatives, so it estimates the
    variance over the cell's points, of which the 4 are a sample). Pairing each sample
    with itself, (sum Y / K)^2, adds V/K = 0.5 to the marginal moment: the variance
    comes out 3.5 and the bias 2.31, which the tests must reject."""
    import renderers.caches.moment_grid as moment_grid

    if planted:
        monkeypatch.setattr(moment_grid, "marginal_second_moment",
                            lambda sum_y, sum_y2, k: dr.square(sum_y / k))
    k, cells = 8, 200
    cache = grid(samples_per_vertex=k)
    rng = np.random.default_rng(7)
    means = rng.choice([0.5, 1.0, 2.0, 4.0], size=(cells, 4))
    sigmas = np.full_like(means, 2.0)
    slot = feed(mi, cache, means, sigmas, 30, rng, k)
    first = np.asarray(slot)[::4]
    value = cache.lookup(points(mi, (np.arange(cells)[:, None] + 0.5) * CELL
                                * np.array([[1.0, 0.0, 0.0]])), up(mi, cells))
    assert dr.all(value.found)
    variance, bias2 = np.asarray(value.local_variance), np.asarray(value.squared_bias)
    radiance = np.asarray(value.radiance)[0]
    assert len(set(first.tolist())) == cells
    p_values = [stats.ttest_1samp(variance, 4.0).pvalue,
                stats.ttest_1samp(bias2, np.var([0.5, 1, 2, 4])).pvalue,
                stats.ttest_1samp(radiance, 1.875).pvalue]
    if planted:
        assert min(p_values[:2]) < 1e-6, p_values
    else:
        assert min(p_values) > 1e-3, p_values


def test_history_caps_the_average(mi):
    """Beyond max_history observations the moments follow a change of the light."""
    k = 4
    cache = grid(samples_per_vertex=k, max_history=8)
    rng = np.random.default_rng(3)
    feed(mi, cache, np.full((1, 4), 1.0), np.zeros((1, 4)), 10, rng, k)
    feed(mi, cache, np.full((1, 4), 3.0), np.zeros((1, 4)), 10, rng, k)
    value = cache.lookup(points(mi, np.array([[0.5 * CELL, 0, 0]])), up(mi))
    assert np.asarray(value.radiance)[0, 0] == pytest.approx(3.0, rel=1e-3)


def test_jitter_blends_neighbouring_records(mi):
    """A point a quarter cell from a border reads its neighbour a quarter of the time
    when jittered (half a cell in the tangent plane), never when not."""
    cache = grid()
    cells = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]]) * CELL
    slot, _ = cache.find(points(mi, cells), up(mi, 2), True, insert=True)
    grey = mi.Float(np.repeat([1.0, 2.0], cache.config.samples_per_vertex))
    cache.accumulate(slot, mi.Color3f(grey, grey, grey), mi.Bool(True))
    n = 20000
    at = np.tile([[0.75 * CELL, 0.5 * CELL, 0.5 * CELL]], (n, 1))
    sampler = np.random.default_rng(5).uniform(size=(n, 2))
    sample = mi.Point2f(mi.Float(sampler[:, 0]), mi.Float(sampler[:, 1]))
    jittered = np.asarray(cache.lookup(points(mi, at), up(mi, n), sample).radiance)[0]
    assert set(np.unique(jittered)) == {1.0, 2.0}
    assert np.mean(jittered == 2.0) == pytest.approx(0.25, abs=0.02)
    still = grid(jitter=False)
    still.find(points(mi, cells), up(mi, 2), True, insert=True)
    still.accumulate(slot, mi.Color3f(grey, grey, grey), mi.Bool(True))
    assert set(np.unique(np.asarray(still.lookup(points(mi, at), up(mi, n), sample)
                                    .radiance)[0])) == {1.0}


def test_representative_vertices_round_trip(mi):
    cache = grid(vertices_per_record=4)
    at = np.array([[0.51, 0.52, 0.53], [0.54, 0.55, 0.56], [2.5, 0.5, 0.5]]) * CELL
    slot, _ = cache.find(points(mi, at), up(mi, 3), True, insert=True)
    cache.store_vertices(slot, points(mi, at), up(mi, 3), mi.Float([0.1, 0.6, 0.0]),
                         mi.Bool(True))
    stored_slot, position, normal = cache.representatives()
    assert sorted(np.asarray(stored_slot).tolist()) == sorted(np.asarray(slot).tolist())
    assert np.allclose(np.sort(np.asarray(position)[0]), np.sort(at[:, 0]))
    assert np.allclose(np.asarray(normal)[2], 1.0)


VERTICES = 32768


def _contended_pass(mi, cache, rng) -> dict[str, np.ndarray]:
    """One pass in which many lanes race: 32768 points of 512 cells of a 1024-slot table
    inserted at once (probe chains collide), their samples summed into those records
    and stored as representatives, many lanes per place. 32768 vertices x K = 4
    samples span 8 of Dr.Jit's thread blocks (16384 lanes each)."""
    k = cache.config.samples_per_vertex
    cells = rng.integers(0, 8, size=(512, 3))
    centres = (cells[rng.integers(0, 512, size=VERTICES)] + rng.random((VERTICES, 3))) * CELL
    p = points(mi, centres)
    slot, found = cache.find(p, up(mi, VERTICES), True, insert=True)
    samples = mi.Color3f(*(mi.Float(rng.lognormal(0.0, 1.5, VERTICES * k)
                                    .astype(np.float32)) for _ in range(3)))
    cache.accumulate(slot, samples, found,
                     mi.Float(rng.random(VERTICES * k).astype(np.float32)))
    choice = mi.Float(rng.random(VERTICES).astype(np.float32))
    cache.store_vertices(slot, p, up(mi, VERTICES), choice, found)
    return {name: np.array(array) for name, array in cache.arrays().items()}


def _twice_on_two_threads(mi) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    previous = dr.thread_count()
    dr.set_thread_count(2)
    try:
        return tuple(_contended_pass(mi, grid(log2_table_size=10, samples_per_vertex=4),
                                     np.random.default_rng(7)) for _ in range(2))
    finally:
        dr.set_thread_count(previous)


def _float_atomic_sum(value, index, active, size):
    """The sum that float atomics give (the planted defect): order-dependent bits."""
    import mitsuba as mi

    total = dr.zeros(mi.Float, size)
    dr.scatter_add(total, value, index, active)
    return total


def test_a_pass_on_two_threads_is_reproducible_bit_for_bit(mi, monkeypatch):
    """Two threads, the same inputs twice: every array of the grid is the same bits (keys
    and representatives despite their races, moments despite the summation order).
    Planted: the sums by float atomics; within 12 repeats a pass differs in its moments
    (the threads' order varies: 9 repeats in 10 differed on a loaded 2-core machine)."""
    from renderers.caches import moment_grid

    first, second = _twice_on_two_threads(mi)
    assert (first["count"] > 0).sum() > 250
    for name in first:
        np.testing.assert_array_equal(first[name], second[name], err_msg=name)

    monkeypatch.setattr(moment_grid, "order_free_sum", _float_atomic_sum)
    for _ in range(12):
        first, second = _twice_on_two_threads(mi)
        if any(not np.array_equal(first[name], second[name])
               for name in ("mean", "second", "marginal", "deferred", "bias")):
            return
    raise AssertionError("float atomics summed alike in 12 repeats")
