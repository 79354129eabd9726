"""Deferred cache queries (renderers/integrators/deferred.py): the network runs on
exactly the queries whose value is used, and a frame whose paths need more
buffer slots than it had is traced again, dropping nothing.

Counts are compared with the AOV ``cache_vertices`` (vertices at which a path
added a cache term) at 1 spp with a box filter, where a pixel is one path. The
scenes are closed boxes lit by a point light: every camera ray hits a surface,
and on the diffuse box every smooth BSDF sample has a positive pdf, so every
cache vertex makes all of its queries.
"""

from __future__ import annotations

import numpy as np
import pytest

from renderers.methods import parse_params
from tests.renderers.scene_xml import CLOSED_BOX, DIFFUSE

RES = 24

# Plastic: a delta coating over a diffuse base. A biased path whose continuation
# picks the coating goes on after terminating its smooth part into the cache,
# and may terminate again at a later vertex.
PLASTIC = '<bsdf type="plastic"/>'


def _scene(mi, tmp_path, bsdf: str):
    from renderers.scenes import load_scene

    xml = tmp_path / "box.xml"
    xml.write_text(CLOSED_BOX.format(res=RES, bsdf=bsdf))
    return load_scene(str(xml), RES)


def _integrator(scene, method: str, **values):
    from renderers.methods import nirc, nrc

    build = {"nirc": nirc.build, "nrc": nrc.build}[method]
    integrator, _trainer, cache = build(scene, parse_params(method, values), 5)
    integrator.cache = cache
    return integrator


def _render(mi, scene, integrator, seed: int = 0) -> tuple[np.ndarray, int]:
    """(film, cache queries evaluated) of one 1-spp frame."""
    integrator.query_counts.clear()
    film = np.asarray(mi.render(scene.scene, integrator=integrator, spp=1, seed=seed))
    return film, sum(count.queries for count in integrator.query_counts)


def _cache_vertices(film: np.ndarray) -> np.ndarray:
    return np.rint(film[..., 5]).astype(int)   # AOVs: depth, cache_depth, cache_vertices


def test_no_query_is_evaluated_where_no_path_uses_the_cache(mi, tmp_path):
    """Adaptive termination with an empty v1 mask and max_depth 2 (no vertex after
    v1 may extend the path, so none uses the cache): zero queries evaluated."""
    scene = _scene(mi, tmp_path, DIFFUSE)
    integrator = _integrator(scene, "nirc", estimator="biased", termination="adaptive",
                             nc=[8, 4], max_depth=2)
    integrator.set_v1_mask(np.zeros((RES, RES), bool))
    film, queries = _render(mi, scene, integrator)
    assert queries == 0
    assert not _cache_vertices(film).any()
    # The same integrator with every pixel allowed at v1: 8 queries per path.
    integrator.set_v1_mask(np.ones((RES, RES), bool))
    film, queries = _render(mi, scene, integrator)
    assert _cache_vertices(film).sum() == RES * RES
    assert queries == 8 * RES * RES


def test_the_deferred_pass_draws_n_c_queries_per_cache_vertex(mi, tmp_path, monkeypatch):
    """Adaptive (nc 4,2; half the pixels may terminate at v1): the deferred pass draws
    4 directions at each path that terminated at v1 and 2 at each that terminated
    later (on the diffuse box a path has at most one cache vertex), and nothing
    elsewhere. Twin: an integrator whose vertices draw N_c + 1 is caught."""
    scene = _scene(mi, tmp_path, DIFFUSE)
    integrator = _integrator(scene, "nirc", estimator="biased", termination="adaptive",
                             nc=[4, 2], max_depth=8)
    integrator.set_v1_mask(np.indices((RES, RES)).sum(axis=0) % 2 == 0)
    film, queries = _render(mi, scene, integrator)
    depth = np.rint(film[..., 4]).astype(int)   # cache_depth: 1 + the vertex index
    assert (depth == 1).any() and (depth > 1).any()
    expected = 4 * (depth == 1).sum() + 2 * (depth > 1).sum()
    assert queries == expected
    assert _cache_vertices(film).sum() == (depth > 0).sum()

    draw = integrator.drawn_query
    monkeypatch.setattr(integrator, "drawn_query",
                        lambda si, bsdf, rng, slot, count: draw(si, bsdf, rng, slot, count + 1))
    _, twin_queries = _render(mi, scene, integrator)
    assert twin_queries != expected


@pytest.mark.parametrize("nc", [1, 4])
def test_biased_bth_evaluates_n_c_queries_per_terminated_vertex(mi, tmp_path, nc):
    scene = _scene(mi, tmp_path, DIFFUSE)
    integrator = _integrator(scene, "nirc", estimator="biased", termination="bth", nc=[nc],
                             max_depth=8)
    film, queries = _render(mi, scene, integrator)
    terminated = _cache_vertices(film).sum()
    assert terminated > 0
    assert queries == nc * terminated
    assert integrator.query_counts[0].slots_per_lane == nc


def test_unbiased_and_nrc_query_counts(mi, tmp_path):
    """Unbiased (3,1,1): N_c + 1 queries (L_c and the residual) at each of a path's
    cache vertices; NRC: one query per terminated path."""
    scene = _scene(mi, tmp_path, DIFFUSE)
    unbiased = _integrator(scene, "nirc", estimator="unbiased", nc=[3, 1, 1], max_depth=8)
    film, queries = _render(mi, scene, unbiased)
    per_path = np.array([0, 4, 6, 8])   # queries of a path with 0..3 cache vertices
    assert queries == per_path[_cache_vertices(film)].sum() > 0
    film, queries = _render(mi, scene, _integrator(scene, "nrc", max_depth=8))
    assert queries == _cache_vertices(film).sum() > 0


def test_a_frame_needing_more_slots_is_traced_again_with_the_same_samples(mi, tmp_path):
    """On plastic, biased paths terminate into the cache at several vertices (delta
    continuations go on). The buffer starts with one cache vertex per lane; the
    frame that needs more is traced again: every query is evaluated, and the image
    equals, bit for bit, that of an integrator whose buffer was large enough."""
    scene = _scene(mi, tmp_path, PLASTIC)
    values = {"estimator": "biased", "termination": "bth", "nc": [2], "max_depth": 8}
    grown = _integrator(scene, "nirc", **values)
    film, queries = _render(mi, scene, grown, seed=3)
    most = _cache_vertices(film).max()
    assert most >= 2
    assert grown.vertex_slots == most
    assert queries == 2 * _cache_vertices(film).sum()

    roomy = _integrator(scene, "nirc", **values)
    roomy.vertex_slots = most + 2
    film_roomy, queries_roomy = _render(mi, scene, roomy, seed=3)
    assert queries_roomy == queries
    np.testing.assert_array_equal(film_roomy, film)


def test_method_stats_report_the_queries(mi, tmp_path):
    from renderers.methods import get_method

    scene = _scene(mi, tmp_path, DIFFUSE)
    params = parse_params("nirc", {"estimator": "biased", "nc": [2], "max_depth": 8,
                                   "min_train_paths": 64})
    out = get_method("nirc").render(scene, params, seed_parts=("q",), spp=1, frames=2)
    stats, path_stats = out.method_stats, out.path_stats
    # 1 spp: one lane per pixel, 2 slots per lane, 2 queries per cache vertex.
    assert stats["cache_queries_per_frame"] == pytest.approx(
        2 * RES * RES * path_stats["avg_cache_vertices"])
    assert stats["cache_query_fraction"] == pytest.approx(path_stats["avg_cache_vertices"])
    assert stats["cache_inline_frames"] == 0
    assert out.timings["stages"]["inference"]["mean_s"] > 0


@pytest.mark.parametrize("estimator", ["biased", "unbiased"])
def test_a_frame_too_large_for_the_buffer_evaluates_its_queries_in_the_loop(
        mi, tmp_path, monkeypatch, estimator):
    """Above MAX_QUERY_SLOTS no buffer is allocated: the queries are evaluated in the
    loop (masked, as before deferral), with the same random numbers, so the image
    equals the deferred one up to float summation order."""
    from renderers.integrators import cached
    from tests.support.oracle import ZeroCache

    scene = _scene(mi, tmp_path, PLASTIC)
    integrator = _integrator(scene, "nirc", estimator=estimator, nc=[3], max_depth=8)
    deferred, queries = _render(mi, scene, integrator, seed=4)
    assert queries > 0
    monkeypatch.setattr(cached, "MAX_QUERY_SLOTS", 0)
    integrator.query_counts.clear()
    inline = np.asarray(mi.render(scene.scene, integrator=integrator, spp=1, seed=4))
    assert integrator.query_counts == [None]
    np.testing.assert_allclose(inline, deferred, rtol=1e-4, atol=1e-6)
    integrator.cache = ZeroCache()   # the cache term is not 0 (else the test says nothing)
    without = np.asarray(mi.render(scene.scene, integrator=integrator, spp=1, seed=4))
    assert not np.allclose(without[..., :3], deferred[..., :3], rtol=1e-3)


@pytest.mark.parametrize("estimator", ["biased", "unbiased"])
def test_a_frame_in_stages_renders_the_integrators_own_image(mi, tmp_path, estimator):
    """A method's frame in frozen stages (renderers.methods.staged: the trace, the deferred
    passes, the film splat of each lane's cache sum) against ``mi.render`` of the same
    integrator and seeds (one splat of path + cache): equal up to float rounding, with
    the same queries. On plastic a biased trace also outgrows its buffer and is traced
    again (the recording's key includes the buffer's size)."""
    from renderers.frozen import frozen_frames
    from renderers.methods.staged import StagedRender
    from renderers.timing import StageTimer

    scene = _scene(mi, tmp_path, PLASTIC)
    values = {"estimator": estimator, "nc": [2], "max_depth": 8,
              **({"termination": "bth"} if estimator == "biased" else {})}
    with frozen_frames(True):
        integrator = _integrator(scene, "nirc", **values)
        frame = StagedRender(scene, integrator, 1)
        staged = [np.asarray(frame(index, 10 + index, StageTimer())) for index in range(4)]
    assert frame.recordings() >= 4   # trace, vertex and query passes, splat
    direct = _integrator(scene, "nirc", **values)
    for index, image in enumerate(staged):
        film, queries = _render(mi, scene, direct, seed=10 + index)
        assert integrator.query_counts[index].queries == queries > 0
        np.testing.assert_allclose(image, film, rtol=1e-4, atol=1e-6)
    assert integrator.vertex_slots == direct.vertex_slots
