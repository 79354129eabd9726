"""`restir-di` (renderers.integrators.restir): screen-space ReSTIR DI at primary hits.

The estimator is direct light only, so the reference is Mitsuba's ``path`` at
max_depth 2 on `many-lights` (32 small lights behind partitions). ``replicas``
independent reservoir chains per pixel give independent samples of one frame's
estimate, whose per-replica mean and variance enter the tests of
tests/renderers/test_light_sampling.py (``agreement_test``: per-pixel Šidák
z-test and aggregate block test, luminance only):

* RIS alone (8 candidates, one shadow ray) agrees with ``path``;
* with temporal reuse (pixels stay independent) it agrees after several frames;
* with temporal and spatial reuse (pixels of a replica share samples, so the
  block test's independence does not hold) every pixel passes the z-test and
  the image mean agrees over the replicas;
* planted: the source pdf of the power-sampled candidates taken as uniform
  (1/32 instead of the power pmf) is rejected, and so are spatial reuse's MIS
  weights with the other pixels' targets taken without their shadow rays, and
  two errors in its pairwise weights: the canonical weight without its 1/k, and
  the canonical sample's pair weights without the neighbours' shadow rays.

Temporal reuse must also do its job: on a static scene the error of frame 8 is
well below frame 1's with reuse, and not without.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from metrics.errors import mrse
from metrics.statistics import agreement_test, z_test
from tests.renderers.lighting import RES, luminance_moments
from tests.support.moments import FLOAT32_REL_PRECISION, render_moments

REPLICAS = 2048          # independent chains per pixel: the samples of the tests
REFERENCE_SPP = 4096
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # Y of linear sRGB (mi.luminance)


def _params(**values):
    base = dict(candidates=8, temporal=False, m_clamp=20.0, spatial=False,
                spatial_neighbours=3, spatial_radius=32.0)
    return SimpleNamespace(**{**base, **values})


@pytest.fixture(scope="module")
def many_lights(mi):
    from renderers.scenes import load_scene

    return load_scene("many-lights", RES).scene


@pytest.fixture(scope="module")
def reference(mi, many_lights):
    return luminance_moments(render_moments(many_lights, {"type": "path", "max_depth": 2},
                                            REFERENCE_SPP, seed=1000))


def _moments(restir, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, variance of the mean, per-replica luminance images) of the last of ``frames``."""
    for frame in range(frames):
        image = np.asarray(restir.render(seed * 1000 + frame))
    y = image[..., :3] @ LUMINANCE
    mean = y.mean(axis=0)
    variance = y.var(axis=0, ddof=1) / len(y) + (FLOAT32_REL_PRECISION * mean) ** 2
    return mean, variance, y


def _restir(scene, replicas=REPLICAS, **params):
    from renderers.integrators.restir import ReSTIRDI

    return ReSTIRDI(scene, _params(**params), replicas=replicas)


def test_parameters_are_validated_and_the_method_registered():
    from renderers.methods import METHODS, MethodError, parse_params

    params = parse_params("restir-di", {})
    assert (params.candidates, params.m_clamp, params.spatial_radius, params.max_depth) == \
        (8, 20.0, 32.0, 2)
    for bad in ({"max_depth": 3}, {"candidates": 0}, {"spatial_radius": 0}):
        with pytest.raises(MethodError, match=next(iter(bad))):
            parse_params("restir-di", bad)
    method = METHODS["restir-di"]
    assert method.applies_to(SimpleNamespace(shape_count=1, emitter_count=2,
                                             area_emitter_count=1, has_envmap=True))[0] is False


def test_the_reference_depth_is_the_methods():
    from jobs.protocol.job import RenderJob
    from jobs.protocol.spec import RenderSpec

    assert RenderJob.parse(RenderSpec(scene="many-lights", method="restir-di")).max_depth == 2
    assert RenderJob.parse(RenderSpec(scene="many-lights", method="pt")).max_depth == -1


def test_temporal_confidence_is_clamped(mi, many_lights):
    restir = _restir(many_lights, replicas=1, temporal=True, m_clamp=2.0)
    for frame in range(4):
        restir.render(frame)
    # clamp(M_prev) + C = 2 C + C
    assert float(np.max(restir.history.reservoirs.M.numpy())) == 24.0


@pytest.mark.slow
def test_ris_without_reuse_matches_path(mi, many_lights, reference):
    mean, variance, _ = _moments(_restir(many_lights), frames=1, seed=1)
    result = agreement_test(mean, variance, *reference, alpha=0.01)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_uniform_source_pdf_for_power_sampled_candidates_is_rejected(mi, many_lights, reference):
    """Candidates drawn by power, but their RIS weight divides by the uniform pmf."""
    from renderers.integrators.lights import PowerLightSampler

    class UniformPmf(PowerLightSampler):
        def sample(self, si, u, active):
            index, _, u_x = super().sample(si, u, active)
            return index, mi.Float(1 / self.count), u_x

    restir = _restir(many_lights)
    restir.lights = UniformPmf(many_lights)
    mean, variance, _ = _moments(restir, frames=1, seed=2)
    result = agreement_test(mean, variance, *reference, alpha=0.01)
    assert not result.passed, result.summary()


@pytest.mark.slow
def test_temporal_reuse_matches_path(mi, many_lights, reference):
    mean, variance, _ = _moments(_restir(many_lights, temporal=True), frames=4, seed=3)
    result = agreement_test(mean, variance, *reference, alpha=0.01)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_temporal_and_spatial_reuse_match_path(mi, many_lights, reference):
    mean, variance, y = _moments(_restir(many_lights, temporal=True, spatial=True),
                                 frames=4, seed=4)
    pixels = z_test(mean, variance, *reference, alpha=0.01)
    assert pixels.passed, pixels.summary()
    # The image mean: one value per replica, independent across replicas.
    image_means = y.mean(axis=(1, 2))
    ref_mean, ref_variance = reference
    z = (image_means.mean() - ref_mean.mean()) / np.sqrt(
        image_means.var(ddof=1) / len(image_means) + ref_variance.sum() / ref_mean.size**2)
    assert abs(z) < 3.3, z  # two-sided p = 0.001


@pytest.mark.slow
def test_spatial_mis_weights_without_visibility_are_rejected(mi, many_lights, reference,
                                                             monkeypatch):
    """The shortcut of taking the other pixels' targets p̂_{x_k}(y_j) without their
    shadow rays in the MIS weights: a neighbour that cannot see y_j still takes a share,
    so the weights of the samples it could have produced no longer sum to 1 (measured:
    86 of 256 pixels flagged, image mean 2.3 % dark)."""
    from renderers.integrators import restir

    combine, visible = restir.combine, restir.visible

    def blind_combine(*args):
        monkeypatch.setattr(restir, "visible", lambda scene, si, r, active: active)
        try:
            return combine(*args)
        finally:
            monkeypatch.setattr(restir, "visible", visible)

    monkeypatch.setattr(restir, "combine", blind_combine)
    mean, variance, _ = _moments(_restir(many_lights, temporal=True, spatial=True),
                                 frames=4, seed=4)
    result = z_test(mean, variance, *reference, alpha=0.01)
    assert not result.passed, result.summary()


def _swapped_during_combine(restir, monkeypatch, name, replace):
    """Plant: ``restir.<name>`` is ``replace(original, si, inputs)`` while ``combine`` runs."""
    combine, original = restir.combine, getattr(restir, name)

    def planted(scene, si, inputs, sampler):
        monkeypatch.setattr(restir, name, replace(original, si, inputs))
        try:
            return combine(scene, si, inputs, sampler)
        finally:
            monkeypatch.setattr(restir, name, original)

    monkeypatch.setattr(restir, "combine", planted)


def _canonical_without_1_over_k(restir, monkeypatch):
    """The canonical sample's weight m_c = Σ_i b_i instead of (1/k) Σ_i b_i: its w times k."""

    def scaled(stream, _si, inputs):
        canonical, k = inputs[0][0], len(inputs) - 1
        return lambda chosen, w_sum, candidate, w, u: stream(
            chosen, w_sum, candidate, w * k if candidate[0] is canonical else w, u)

    _swapped_during_combine(restir, monkeypatch, "stream", scaled)


def _canonical_pairs_without_visibility(restir, monkeypatch):
    """b_i(y_c) with the neighbour's target p̂_i(y_c) without its shadow ray (the rays from
    the pixel's own x toward the neighbours' samples stay)."""

    def from_own_point(visible, si, _inputs):
        return lambda scene, si_k, r, active: (visible(scene, si_k, r, active) if si_k is si
                                               else active)

    _swapped_during_combine(restir, monkeypatch, "visible", from_own_point)


@pytest.mark.slow
@pytest.mark.parametrize("plant, params, frames", [
    (_canonical_without_1_over_k, dict(spatial=True), 1),
    (_canonical_pairs_without_visibility, dict(temporal=True, spatial=True), 4),
])
def test_wrong_pairwise_mis_weights_are_rejected(mi, many_lights, reference, monkeypatch,
                                                 plant, params, frames):
    """Planted errors in the pairwise weights of spatial reuse, rejected by the per-pixel
    test: the canonical weight without its 1/k (the weights sum to more than 1; measured:
    ~190 of 256 pixels flagged, image mean ~49 % bright after one frame), and the canonical
    sample's pair weights b_i(y_c) with neighbours that cannot see y_c still taking a
    share (the weights sum to less than 1; 159 of 256 flagged, 5.6 % dark after 4 frames;
    one frame of spatial reuse alone flags only 4)."""
    from renderers.integrators import restir

    plant(restir, monkeypatch)
    mean, variance, _ = _moments(_restir(many_lights, **params), frames=frames, seed=4)
    result = z_test(mean, variance, *reference, alpha=0.01)
    assert not result.passed, result.summary()


def _floor_view(mi, resolution: int):
    """`many-lights` from below the lights (renderers.scenes.many_lights.floor_view)."""
    from renderers.scenes.many_lights import floor_view
    from renderers.scenes.parts import set_film_resolution

    return mi.load_dict(set_film_resolution(floor_view(), resolution, resolution),
                        optimize=False)


def _frame_errors(scene, reference: np.ndarray, frames: int, **params) -> list[float]:
    """MRSE of each of ``frames`` frames, the mean over 4 independent chains."""
    restir = _restir(scene, replicas=4, **params)
    return [float(np.mean([mrse(image[..., :3], reference)
                           for image in np.asarray(restir.render(100 + f))]))
            for f in range(frames)]


@pytest.mark.slow
def test_temporal_reuse_lowers_the_error_over_frames(mi):
    """Static camera, 64 x 64: with temporal reuse frame 8's MRSE is well below frame 1's
    (measured 0.16 x), without reuse it stays (1.0 x)."""
    scene = _floor_view(mi, 64)
    reference = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 2}),
                                     spp=1024, seed=7))[..., :3]
    reused = _frame_errors(scene, reference, 8, temporal=True)
    fresh = _frame_errors(scene, reference, 8)
    print(f"MRSE frame 8 / frame 1: reuse {reused[-1] / reused[0]:.3f}, "
          f"none {fresh[-1] / fresh[0]:.3f}")
    assert reused[-1] < 0.4 * reused[0]
    assert fresh[-1] > 0.8 * fresh[0]


def _after_switch_on(mi, frames_off: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, variance of the mean, per-replica images) of the frame where `many-lights-switch`'s
    8 lights switch on again, after ``frames_off`` frames of temporal reuse without them."""
    from renderers.scenes import load_scene

    animated = load_scene("many-lights-switch", SWITCH_RES)
    restir = _restir(animated.scene, replicas=SWITCH_REPLICAS, temporal=True)
    animated.player.apply(6)
    for frame in range(frames_off):
        restir.render(seed * 1000 + frame)
    animated.player.apply(12)
    return _moments(restir, frames=1, seed=seed + 1)


SWITCH_RES = 8
SWITCH_REPLICAS = 1024


@pytest.mark.parametrize("planted", [False, True])
def test_temporal_reuse_is_unbiased_when_lights_switch_on(mi, monkeypatch, planted):
    """The frame where lights switch on agrees with ``path`` (per pixel and blocks). Planted:
    the previous reservoirs reused across the change (their pair weights a_i take a share of
    the canonical sample's weight on the lights just switched on, which they could not have
    sampled: measured 10 % dark over the lit pixels at 8x8 after 12 frames off with
    M_prev 160; here 3 frames, M_prev 32), rejected."""
    from renderers.integrators import restir
    from renderers.scenes import load_scene

    if planted:   # the history's scene state never differs: it survives the switch
        monkeypatch.setattr(restir, "scene_generation", lambda scene: 0)
    scene = load_scene("many-lights-switch", SWITCH_RES).scene   # as loaded: all lights on
    reference = luminance_moments(render_moments(scene, {"type": "path", "max_depth": 2},
                                                 REFERENCE_SPP, seed=1001))
    mean, variance, _ = _after_switch_on(mi, frames_off=3, seed=5)
    result = agreement_test(mean, variance, *reference, alpha=0.01)
    assert result.passed != planted, result.summary()


@pytest.mark.parametrize("planted", [False, True])
def test_a_frozen_frame_writes_no_constant_of_the_history_again(mi, many_lights, monkeypatch,
                                                                planted):
    """A steady frozen frame's only launch before its replay is its seed: the first hits it
    hands to the next frame carry no constant (literal) field, which the next call would
    write into memory again (a memset per field and frame). Planted: the whole surface
    interaction carried (11 memsets per frame on many-lights)."""
    import drjit as dr

    from renderers.frozen import frozen_frames
    from renderers.integrators import restir as module

    if planted:
        monkeypatch.setattr(module.FirstHits, "DRJIT_STRUCT",
                            dict(mi.SurfaceInteraction3f.DRJIT_STRUCT))
    with frozen_frames(True), dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        restir = _restir(many_lights, replicas=1, temporal=True, spatial=True)
        for frame in range(4):
            dr.kernel_history()
            dr.eval(restir.render(frame))
            dr.sync_thread()
        outside = [entry for entry in dr.kernel_history()
                   if entry["recording_mode"] == dr.KernelRecordingMode.Inactive]
    assert restir.recordings() is not None
    assert (len(outside) > 1) == planted, [(e["type"], e["size"]) for e in outside]
