"""The update pass of the hashed-grid moment cache (renderers/integrators/grid_update.py):
its samples are the path tracer's own one-segment estimates, and repeated passes
propagate radiance to the known fixed point of a furnace."""

from __future__ import annotations

import itertools

import drjit as dr
import numpy as np
import pytest
from scipy import stats

pytestmark = pytest.mark.usefixtures("mi")

ALBEDO, RADIANCE = 0.5, 1.0


@pytest.fixture(scope="module")
def furnace(mi):
    """The inside of an emitting diffuse sphere: every point reflects
    L_r = albedo (Le + L_r), so L_r = albedo Le / (1 - albedo) = 1."""
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 90,
                   "film": {"type": "hdrfilm", "width": 12, "height": 12}},
        "sphere": {"type": "sphere", "radius": 1.0, "flip_normals": True,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                               "value": [ALBEDO] * 3}},
                   "emitter": {"type": "area", "radiance": {"type": "rgb",
                                                            "value": [RADIANCE] * 3}}}})


def seeded_grid(mi, scene, **overrides):
    from renderers.caches.grid_config import MomentGridConfig
    from renderers.caches.moment_grid import MomentGrid
    from renderers.integrators.grid_update import GridUpdateIntegrator, store_primary_vertices
    from renderers.integrators.path import register

    register("nirc_grid_update", GridUpdateIntegrator)
    grid = MomentGrid(MomentGridConfig(**{"cell_size": 0.25, "log2_table_size": 12,
                                          "jitter": False, **overrides}))
    store_primary_vertices(scene, grid, scene.sensors()[0], 0, 1.0)
    integrator = mi.load_dict({"type": "nirc_grid_update"})
    integrator.grid = grid
    return grid, integrator


def record_means(grid):
    used = np.asarray(grid.count) > 0
    return np.asarray(grid.mean).reshape(-1, 3)[used, 0]


def test_the_first_pass_is_the_path_tracers_direct_light(mi, furnace):
    """With nothing in the cache, a sample is the core's two-segment estimate at the
    vertex minus the vertex's own emission: the same mean (Welch t-test on the
    samples), and the vertex's emission left in is rejected."""
    from renderers.integrators.grid_update import update_grid
    from renderers.integrators.path import register

    grid, integrator = seeded_grid(mi, furnace, samples_per_vertex=16)
    _, position, normal = grid.representatives()
    samples = []
    original = grid.accumulate
    grid.accumulate = lambda slot, y, active, *rest: (samples.append(np.asarray(y)[0]),
                                                      original(slot, y, active, *rest))
    update_grid(furnace, integrator, seed=1, hit_store_probability=0.0)
    pass_samples = samples[0]

    register()
    path = mi.load_dict({"type": "nirc_path", "max_depth": 2})
    k = grid.config.samples_per_vertex
    owner = dr.arange(mi.UInt32, dr.width(position) * k) // k
    p, n = dr.gather(mi.Point3f, position, owner), dr.gather(mi.Vector3f, normal, owner)
    ray = mi.Ray3f(p + 1e-3 * n, -n)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(2, dr.width(owner))
    core = np.asarray(path.trace(furnace, sampler, ray, mi.Bool(True))[0])[0] - RADIANCE
    assert stats.ttest_ind(pass_samples, core, equal_var=False).pvalue > 1e-3
    assert stats.ttest_ind(pass_samples + RADIANCE, core, equal_var=False).pvalue < 1e-9


@pytest.mark.parametrize("propagate", [True, False], ids=["cache", "planted-no-cache"])
def test_passes_propagate_radiance_to_the_furnace_fixed_point(mi, furnace, monkeypatch,
                                                              propagate):
    """Each pass adds a bounce where the hits find records, and the hits explore the
    sphere: the records' mean rises from the direct light 0.5 towards the fixed point 1
    (0.51, 0.54, 0.60, ... 0.99 after 10 passes; within 2 %: the core's own estimate on
    this sphere is about 0.5 % high, rays grazing the surface near the vertex); without
    the cache's value at the hit it stays at 0.5."""
    from renderers.integrators import grid_update

    if not propagate:
        lookup = grid_update.MomentGrid.lookup
        monkeypatch.setattr(grid_update.MomentGrid, "lookup",
                            lambda self, *a, **kw: type(lookup(self, *a, **kw))(
                                mi.Color3f(0.0), mi.Float(0.0), mi.Float(0.0), mi.Float(0.0),
                                mi.Bool(False), mi.Bool(False)))
    grid, integrator = seeded_grid(mi, furnace, samples_per_vertex=8, max_history=2)
    means = []
    for frame in range(12):
        grid_update.update_grid(furnace, integrator, seed=frame + 1, hit_store_probability=0.1)
        means.append(record_means(grid).mean())
    first = ALBEDO * RADIANCE
    assert means[0] == pytest.approx(first, rel=0.02)
    fixed_point = first / (1 - ALBEDO)
    if propagate:
        assert all(b > a for a, b in itertools.pairwise(means[:8]))
        assert means[-1] == pytest.approx(fixed_point, rel=0.02)
    else:
        assert means[-1] == pytest.approx(first, rel=0.02)
