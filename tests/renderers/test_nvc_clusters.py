"""The clustered neural visibility cache (`nvc-lights` with clusters) and `restir-nvc`.

Fast checks: `many-lights-300` loads with 300 lights of varied power; k-means
clusters partition the lights deterministically (an environment gets its own
cluster); the selector's source pmf sums to 1 and ``sample``/``select`` return
``pmf``'s value; training targets are per-cluster visibility. The streaming-RIS
contribution weight W of the in-cluster pick is tested directly: at fixed
shading points, E[W U_l 1{l in c}] must equal sum_{l in c} U_l for every cluster
c (per-cluster z-test, Šidák, over 2^18 picks per point), and the planted
source pdf without the uniform pick's 1 / m_c is rejected by the same test.
`restir-nvc` renders through its own frame loop (pre-training, training, reuse).

Statistical checks (slow) as tests/renderers/test_nvc_lights.py: after a few
frames of training, clustered `nvc-lights` agrees with Mitsuba's ``path``
(per-pixel Šidák z-test and aggregate test, Y channel) on `many-lights` forced
into 4 clusters and on `many-lights-300` (32 clusters), direct light only
(max_depth 2) and full global illumination (max_depth -1); 1024 spp on both
sides except 4096 for `many-lights-300` direct. The planted RIS
weight without 1 / m_c is rejected on `many-lights-300`. With clamp 0 and a
cache that calls a cluster of two point lights occluded everywhere, the image
is rejected, with clamp 0.001 it agrees. With four large lights just above a
floor (BSDF sampling hits them often, so MIS matters) the estimator agrees,
and NEE's MIS weight taken with 1 / W as its light pmf (while BSDF hits use the
source pmf: the weights no longer sum to one) is rejected. `restir-nvc`'s RIS alone (no reuse)
agrees with ``path`` on `many-lights-300` and (per-light NVC) on `many-lights`,
and its planted candidate pdf
without 1 / m_c is rejected.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from metrics.statistics import agreement_test, z_test
from tests.renderers.lighting import RES, SPP, luminance_moments, trained_nvc_lights
from tests.renderers.scene_xml import perspective_sensor
from tests.renderers.test_nvc_lights import SHADOWED_FLOOR, _blind_to_light, _reference
from tests.renderers.test_restir import _moments, _params
from tests.support.moments import render_moments

TRAIN_FRAMES = 4
TRAIN_POINTS = {"world_points": 1024, "camera_points": 1024}
RIS_PICKS = 1 << 18      # NEE picks per shading point of the direct RIS-weight test
RESTIR_REPLICAS = 512    # independent reservoir chains per pixel of the restir-nvc tests
LOW_SPP = 1024           # spp (both sides) of the image tests but 300 lights' direct one


@pytest.fixture(scope="module")
def many_lights(mi):
    from renderers.scenes import load_scene

    return load_scene("many-lights", RES)


@pytest.fixture(scope="module")
def lights_300(mi):
    from renderers.scenes import load_scene

    return load_scene("many-lights-300", RES)


def _trained(scene, frames=TRAIN_FRAMES, seed=0, **params):
    return trained_nvc_lights(scene, frames, seed, **{**TRAIN_POINTS, **params})


def _without_uniform_pick(sampler_type):
    """Planted: the in-cluster pick's source pdf taken as P(c) (the 1 / m_c dropped),
    in NEE's RIS weight and in ``sample``'s pmf (the ReSTIR candidates' source)."""

    class Planted(sampler_type):
        def _size(self, index):
            import drjit as dr
            import mitsuba as mi

            cluster = dr.gather(mi.UInt32, self.labels, index)
            return mi.Float(dr.gather(mi.UInt32, self.sizes, cluster))

        def select(self, si, u, active):
            index, weight, pmf, u = super().select(si, u, active)
            return index, weight / self._size(index), pmf, u

        def sampler_at(self, si, active):
            draw = super().sampler_at(si, active)

            def planted(u):
                index, pmf, u_x = draw(u)
                return index, pmf * self._size(index), u_x
            return planted

    return Planted


# ---------------------------------------------------------------------------
# The scene, the clusters, the selector (fast)
# ---------------------------------------------------------------------------

def test_many_lights_300_has_300_lights_of_varied_power(lights_300):
    from renderers.integrators.lights import emitter_powers

    features = lights_300.features
    assert features.emitter_count == features.area_emitter_count == 300
    assert features.has_many_lights and not features.has_envmap
    powers = emitter_powers(lights_300.scene)
    assert powers.max() / powers.min() > 20


def test_the_method_applies_beyond_32_lights_and_clusters_them(lights_300):
    from renderers.methods import METHODS, MethodError, parse_params

    assert METHODS["nvc-lights"].applies_to(lights_300.features) == (True, "")
    assert METHODS["restir-nvc"].applies_to(lights_300.features) == (True, "")
    assert parse_params("nvc-lights", {}).cluster_count(300) == 32
    assert parse_params("nvc-lights", {}).cluster_count(32) == 0
    assert parse_params("nvc-lights", {"clusters": 4}).cluster_count(32) == 4
    with pytest.raises(MethodError, match="clusters"):
        parse_params("nvc-lights", {"clusters": 33})
    assert METHODS["restir-nvc"].applies_to(SimpleNamespace(
        shape_count=1, emitter_count=1, area_emitter_count=1, has_envmap=False)) == \
        (False, "one emitter: nothing to select")


def test_k_means_partitions_the_lights_deterministically(mi, lights_300):
    from renderers.integrators.nvc_lights import cluster_lights
    from tests.renderers.lighting import ENV_AND_SPHERE

    clusters = cluster_lights(lights_300.scene, 32)
    assert clusters.count == 32 and len(clusters.labels) == 300
    order, sizes, starts = clusters.members()
    assert sorted(order) == list(range(300)) and sizes.sum() == 300 and sizes.min() >= 1
    assert np.all(clusters.labels[order[starts]] == np.arange(32))
    np.testing.assert_array_equal(cluster_lights(lights_300.scene, 32).labels, clusters.labels)
    # An environment has no position: a cluster of its own.
    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    labels = cluster_lights(scene, 1).labels
    assert len(set(labels)) == 2


def test_training_targets_are_per_cluster_visibility(mi, lights_300):
    from renderers.integrators.nvc_lights import cluster_lights, visibility_records

    clusters = cluster_lights(lights_300.scene, 32)
    records = visibility_records(lights_300.scene, 256, 256, seed=1, clusters=clusters)
    targets = np.stack([t.numpy() for t in records.target_rows()])
    assert targets.shape == (32, 512) and set(np.unique(targets)) <= {0.0, 1.0}
    assert 0.05 < targets[:, records.valid.numpy()].mean() < 0.8


def _floor_points(mi, scene, count=64, seed=3):
    """Shading points on the floor (normal up, seen from above) at random x, z."""
    import drjit as dr

    rng = np.random.default_rng(seed)
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    xz = rng.uniform(-3.8, 3.8, size=(2, count))
    si.p = mi.Point3f(mi.Float(xz[0]), 0.0, mi.Float(xz[1]))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 1, 0))
    si.wi = mi.Vector3f(0, 0, 1)
    si.shape = dr.gather(mi.ShapePtr, scene.shapes_dr(), mi.UInt32(0))
    return si, rng


def test_source_pmf_sums_to_one_and_sample_select_return_it(mi, lights_300):
    import drjit as dr

    integrator, _ = _trained(lights_300, frames=2)
    sampler = integrator.light_sampler(lights_300.scene)
    si, rng = _floor_points(mi, lights_300.scene)
    # Every (point, light) pair in one query: lane = point * 300 + light.
    lane = np.arange(64 * 300, dtype=np.uint32)
    pairs = dr.gather(mi.SurfaceInteraction3f, si, mi.UInt32(lane // 300))
    pmfs = sampler.pmf(pairs, mi.UInt32(lane % 300), True).numpy().reshape(64, 300)
    np.testing.assert_allclose(pmfs.sum(axis=1), 1.0, rtol=1e-4)
    index, pmf, u = sampler.sample(si, mi.Float(rng.uniform(size=64)), True)
    np.testing.assert_allclose(pmf.numpy(), sampler.pmf(si, index, True).numpy(), rtol=1e-5)
    assert np.all((u.numpy() >= 0) & (u.numpy() < 1))
    u2 = mi.Point2f(*(mi.Float(rng.uniform(size=64)) for _ in range(2)))
    index, weight, pmf, _ = sampler.select(si, u2, True)
    np.testing.assert_allclose(pmf.numpy(), sampler.pmf(si, index, True).numpy(), rtol=1e-5)
    assert np.all(weight.numpy() > 0)  # the clamp: every cluster above the floor selectable


def _cluster_ris_test(mi, sampler, points=4):
    """z-test of E[W U_l 1{l in c}] = sum_{l in c} U_l(x) per (point, cluster)."""
    import drjit as dr

    clusters = sampler.clusters
    si, rng = _floor_points(mi, sampler.scene, count=points, seed=5)
    p = [v.numpy() for v in (si.p.x, si.p.z)]
    lanes = points * RIS_PICKS
    point = np.repeat(np.arange(points), RIS_PICKS)
    big, _ = _floor_points(mi, sampler.scene, count=1)
    big = dr.gather(mi.SurfaceInteraction3f, big, mi.UInt32(np.zeros(lanes, dtype=np.uint32)))
    big.p = mi.Point3f(mi.Float(p[0][point]), 0.0, mi.Float(p[1][point]))
    u = mi.Point2f(*(mi.Float(rng.uniform(size=lanes)) for _ in range(2)))
    index, weight, _, _ = sampler.select(big, u, True)
    both = mi.Bool(False)
    value = (weight * sampler.light_unshadowed(big, index, both, True)).numpy()
    cell = point * clusters.count + clusters.labels[index.numpy()]
    cells = points * clusters.count
    sums = np.bincount(cell, weights=value, minlength=cells) / RIS_PICKS
    squares = np.bincount(cell, weights=value**2, minlength=cells) / RIS_PICKS
    variance = (squares - sums**2) / (RIS_PICKS - 1)
    # The exact sums: U_l of every light at every point.
    exact = np.zeros(cells)
    for light in range(sampler.count):
        lights = dr.gather(mi.SurfaceInteraction3f, big, mi.UInt32(np.arange(points) * RIS_PICKS))
        u_l = sampler.light_unshadowed(lights, mi.UInt32(np.full(points, light)), both, True)
        exact[np.arange(points) * clusters.count + clusters.labels[light]] += u_l.numpy()
    return z_test(sums, variance, exact, np.zeros(cells), alpha=0.01)


def test_ris_contribution_weight_is_unbiased_per_cluster(mi, lights_300):
    integrator, _ = _trained(lights_300, frames=2)
    sampler = integrator.light_sampler(lights_300.scene)
    result = _cluster_ris_test(mi, sampler)
    print(result.summary())
    assert result.passed, result.summary()


def test_ris_weight_without_the_uniform_pick_is_rejected(mi, lights_300):
    integrator, _ = _trained(lights_300, frames=2)
    planted = _without_uniform_pick(integrator.light_sampler_type)(lights_300.scene)
    result = _cluster_ris_test(mi, planted)
    print(result.summary())
    assert not result.passed, result.summary()


# ---------------------------------------------------------------------------
# Agreement with Mitsuba's path, planted biases (slow)
# ---------------------------------------------------------------------------

def _spp(max_depth):
    return SPP if max_depth == 2 else LOW_SPP


@pytest.fixture(scope="module")
def references_300(mi, lights_300):
    return {depth: _reference(lights_300.scene, depth, spp=_spp(depth)) for depth in (2, -1)}


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, -1], ids=["direct", "global"])
def test_four_clusters_on_many_lights_match_mitsuba_path(mi, many_lights, max_depth):
    integrator, cache = _trained(many_lights, max_depth=max_depth, clusters=4)
    assert cache.clusters.count == 4 and cache.n_outputs == 4
    test = luminance_moments(render_moments(many_lights.scene, integrator, LOW_SPP, seed=1))
    reference = _reference(many_lights.scene, max_depth, spp=LOW_SPP)
    result = agreement_test(*test, *reference, alpha=0.01)
    print(result.summary())
    assert result.passed, result.summary()


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, -1], ids=["direct", "global"])
def test_300_lights_in_32_clusters_match_mitsuba_path(mi, lights_300, references_300,
                                                      max_depth):
    integrator, cache = _trained(lights_300, max_depth=max_depth)
    assert cache.clusters.count == 32
    test = luminance_moments(render_moments(lights_300.scene, integrator, _spp(max_depth),
                                            seed=1))
    result = agreement_test(*test, *references_300[max_depth], alpha=0.01)
    print(result.summary())
    assert result.passed, result.summary()


@pytest.mark.slow
def test_planted_ris_weight_without_the_uniform_pick_is_rejected_in_the_image(
        mi, lights_300, references_300):
    integrator, _ = _trained(lights_300, max_depth=2)
    integrator.light_sampler_type = _without_uniform_pick(integrator.light_sampler_type)
    test = luminance_moments(render_moments(lights_300.scene, integrator, LOW_SPP, seed=2))
    result = agreement_test(*test, *references_300[2], alpha=0.01)
    print(result.summary())
    assert not result.passed, result.summary()


#: SHADOWED_FLOOR with a second point light next to the first: k-means into 2 clusters
#: puts the two point lights in one and the distant area light in the other.
TWO_POINT_LIGHTS = SHADOWED_FLOOR.replace("</scene>", """    <emitter type="point">
        <point name="position" value="-0.6, 0.4, 0.6"/>
        <rgb name="intensity" value="1, 1, 1"/>
    </emitter>
</scene>""")


@pytest.mark.slow
def test_clamp_zero_is_biased_where_the_cache_wrongly_predicts_a_cluster_occluded(mi):
    """The cluster of the two point lights lights the floor left of the wall; the planted
    cache says it is occluded everywhere. With clamp 0 its pmf is 0 and its light is
    missing (rejected); the paper's clamp 0.001 keeps it selectable: unbiased."""
    scene = mi.load_string(TWO_POINT_LIGHTS.format(res=RES))
    loaded = SimpleNamespace(scene=scene)
    reference = _reference(scene, max_depth=2, spp=LOW_SPP)
    results = {}
    for clamp in (0.0, 0.001):
        integrator, cache = _trained(loaded, frames=2, max_depth=2, clamp=clamp, clusters=2)
        labels = cache.clusters.labels
        assert labels[0] == labels[1] != labels[2]  # the point lights (listed first) share one
        _blind_to_light(cache, int(labels[0]))
        test = luminance_moments(render_moments(scene, integrator, LOW_SPP, seed=2))
        results[clamp] = agreement_test(*test, *reference, alpha=0.01)
        print(f"clamp {clamp}: {results[clamp].summary()}")
    assert not results[0.0].passed, results[0.0].summary()
    assert results[0.001].passed, results[0.001].summary()


#: A floor under four large, low area lights of two sizes and powers (k-means into 2
#: clusters mixes them): BSDF sampling hits the lights often, so MIS weights matter.
LOW_LIGHTS = """<scene version="3.0.0">
    """ + perspective_sensor("60", "0, 4, 0.01", "0, 0, 0") + """
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="2"/></transform>
        <bsdf type="diffuse"/>
    </shape>""" + "".join(f"""
    <shape type="rectangle">
        <transform name="to_world"><scale value="{size}"/><rotate x="1" angle="90"/>
            <translate x="{x}" y="{y}" z="{z}"/></transform>
        <emitter type="area"><rgb name="radiance" value="{radiance}, {radiance}, {radiance}"/></emitter>
    </shape>""" for x, y, z, size, radiance in ((-1, 0.3, -1, 0.6, 1), (-0.6, 0.5, -0.4, 0.3, 8),
                                              (1, 0.3, 1, 0.6, 1), (0.6, 0.5, 0.4, 0.3, 8))) + """
</scene>
"""


@pytest.mark.slow
def test_mis_weights_need_the_same_light_pmf_on_both_sides(mi):
    """NEE's MIS weight uses the exact source pmf, as the BSDF hits' does: agrees. Planted:
    NEE takes 1 / W (its RIS weight) as its light pmf instead, so the two strategies'
    weights no longer sum to one: rejected."""
    import drjit as dr

    scene = mi.load_string(LOW_LIGHTS.format(res=RES))
    loaded = SimpleNamespace(scene=scene)
    reference = _reference(scene, max_depth=2)
    results = {}
    for planted in (False, True):
        integrator, cache = _trained(loaded, frames=2, max_depth=2, clusters=2)
        assert cache.clusters.count == 2
        if planted:
            class RISWeightAsPmf(integrator.light_sampler_type):
                def select(self, si, u, active):
                    index, weight, _, u = super().select(si, u, active)
                    return index, weight, dr.select(weight > 0, dr.rcp(weight), 0), u

            integrator.light_sampler_type = RISWeightAsPmf
        test = luminance_moments(render_moments(scene, integrator, SPP, seed=3))
        results[planted] = agreement_test(*test, *reference, alpha=0.01)
        print(f"planted {planted}: {results[planted].summary()}")
    assert results[False].passed, results[False].summary()
    assert not results[True].passed, results[True].summary()


def _restir_nvc(scene, planted=False):
    """restir-nvc's estimator (RIS alone) after a few frames of training on ``scene``."""
    from renderers.integrators.restir import ReSTIRDI
    from renderers.methods.nvc_lights import light_selection, train_frame
    from renderers.methods.restir_nvc import ReSTIRNVCParams
    from renderers.timing import StageTimer

    params = ReSTIRNVCParams(**TRAIN_POINTS)
    selector, cache = light_selection(scene, params, seed=0)
    for frame in range(TRAIN_FRAMES):
        train_frame(scene, cache, params, frame, StageTimer())
    if planted:
        selector = _without_uniform_pick(selector)
    return ReSTIRDI(scene.scene, _params(), replicas=RESTIR_REPLICAS,
                    lights=selector(scene.scene))


@pytest.mark.slow
@pytest.mark.parametrize("clustered", [True, False], ids=["300-lights", "32-lights"])
def test_restir_with_nvc_candidates_matches_path(mi, lights_300, references_300, many_lights,
                                                 clustered):
    """Candidates from the clustered NVC (300 lights) and from the per-light NVC (32)."""
    scene = lights_300 if clustered else many_lights
    reference = references_300[2] if clustered else _reference(many_lights.scene, 2)
    mean, variance, _ = _moments(_restir_nvc(scene), frames=1, seed=1)
    result = agreement_test(mean, variance, *reference, alpha=0.01)
    print(result.summary())
    assert result.passed, result.summary()


@pytest.mark.slow
def test_restir_nvc_candidate_pdf_without_the_uniform_pick_is_rejected(mi, lights_300,
                                                                       references_300):
    mean, variance, _ = _moments(_restir_nvc(lights_300, planted=True), frames=1, seed=2)
    result = agreement_test(mean, variance, *references_300[2], alpha=0.01)
    print(result.summary())
    assert not result.passed, result.summary()


def test_restir_nvc_renders_through_its_frame_loop(mi):
    """The method's own loop: pre-training, training before every frame, the reservoirs
    (reuse on), the cache's statistics."""
    from renderers.methods import METHODS, parse_params
    from renderers.scenes import load_scene

    scene = load_scene("many-lights", 8)
    params = parse_params("restir-nvc", {"world_points": 256, "camera_points": 256,
                                         "pretrain_frames": 1, "spatial_neighbours": 1})
    output = METHODS["restir-nvc"].render(scene, params, seed_parts=("restir-nvc-test",),
                                          spp=1, frames=2)
    assert output.accumulated.shape[:2] == (8, 8) and np.isfinite(output.accumulated).all()
    assert output.accumulated[..., :3].mean() > 0
    stats = output.method_stats
    assert stats["shadow_rays_per_sample"] == 1 + 2 + 2 and stats["pretrain_frames"] == 1
    assert len(stats["loss_history"]) == 1 + 1 + 2  # pre-training, warm-up, 2 frames
    # Its resolved cache: one output per light of 32, trained on 512 points a frame.
    cache = stats["caches"]["cache"]
    assert cache["config"]["output"]["n_outputs"] == 32
    assert cache["per_frame"] == {"points": 512, "steps": 1, "batch_size": 8192,
                                  "records": 8192}
