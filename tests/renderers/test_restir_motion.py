"""`restir-di`'s temporal reuse along motion vectors (renderers.integrators.restir).

With a moving camera each pixel reuses the previous frame's reservoir where its
first hit x was seen (x projected with the previous camera), rejected where that
pixel saw another surface. The projection is Mitsuba's own (a point's film
position by the sensor's ``sample_direction`` agrees with ours), and the frames of
a camera pan over `many-lights` agree with ``path`` at each frame's camera
(per-pixel Šidák test and aggregate block test; temporal reuse only, so the
replicas' pixels stay independent). Planted: the reused reservoir taken from the
reprojected pixel but its shading point x_i from the same pixel (the pairwise
weights then evaluate the previous target at the wrong point), rejected.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrics.statistics import agreement_test
from tests.renderers.lighting import luminance_moments
from tests.renderers.test_restir import LUMINANCE, _params
from tests.support.moments import FLOAT32_REL_PRECISION, render_moments

RES = 16
REPLICAS = 512
REFERENCE_SPP = 2048
#: Frames of the pan (each with its own camera); all but the first reuse a moved history.
PAN_FRAMES = 4
ALPHA = 0.01


def _pan(mi):
    """`many-lights` with the camera turning and sliding over ``PAN_FRAMES`` frames
    (1-3 px of motion per frame at 16 x 16)."""
    from renderers.scenes import load_scene
    from renderers.scenes.animation import Animation, CameraKey
    from renderers.scenes.loader import animated

    last = PAN_FRAMES - 1
    return animated(load_scene("many-lights", RES), Animation(camera=[
        CameraKey(frame=0, position=(3.7, 2.7, 3.7), target=(-1.0, 0.2, -1.0), fov=75.0),
        CameraKey(frame=last, position=(3.2, 2.7, 3.9), target=(-1.6, 0.2, 0.2), fov=75.0)]))


def test_the_projection_is_the_sensors(mi):
    """World points' film positions in pixels: ours against the sensor's own."""
    import drjit as dr

    from renderers.integrators.restir import CameraProjection

    sensor = _pan(mi).scene.sensors()[0]
    rng = np.random.default_rng(3)
    points = rng.uniform(-2.0, 2.0, (64, 3))
    interaction = dr.zeros(mi.Interaction3f, len(points))
    interaction.p = mi.Point3f(points.T.astype(np.float32))
    ds, _ = sensor.sample_direction(interaction, mi.Point2f(0.5, 0.5))
    seen = np.asarray(ds.pdf) > 0
    h = CameraProjection.of(sensor).to_film @ np.c_[points, np.ones(len(points))].T
    assert seen.sum() > 16
    np.testing.assert_allclose((h[:2] / h[3])[:, seen], np.asarray(ds.uv)[:, seen], atol=1e-3)


def _x_i_from_the_same_pixel(monkeypatch):
    """Plant: the reservoir of the reprojected pixel, the shading point of the pixel's own."""
    from renderers.integrators import restir

    reproject = restir.reproject

    def planted(si, previous, motion, lane, size):
        source, _, kept = reproject(si, previous, motion, lane, size)
        return source, previous.si.interaction(), kept

    monkeypatch.setattr(restir, "reproject", planted)


@pytest.mark.slow
@pytest.mark.parametrize("planted", [False, True])
def test_reuse_along_motion_vectors_is_unbiased(mi, monkeypatch, planted):
    """Each frame after the first agrees with ``path`` at its camera (the frames' tests
    at a Šidák-corrected level, family-wise ``ALPHA``). Planted shading point: rejected
    (measured at 1024 replicas: aggregate chi2 p 1e-3, 3e-5, 3e-15 at frames 1-3)."""
    from metrics.statistics import sidak_alpha
    from renderers.integrators.restir import ReSTIRDI

    if planted:
        _x_i_from_the_same_pixel(monkeypatch)
    pan = _pan(mi)
    restir = ReSTIRDI(pan.scene, _params(temporal=True), replicas=REPLICAS)
    level = sidak_alpha(ALPHA, PAN_FRAMES - 1)
    results = []
    for frame in range(PAN_FRAMES):
        pan.player.apply(frame)
        image = np.asarray(restir.render(7000 + frame))
        if frame == 0:
            continue
        y = image[..., :3] @ LUMINANCE
        mean = y.mean(axis=0)
        variance = y.var(axis=0, ddof=1) / len(y) + (FLOAT32_REL_PRECISION * mean) ** 2
        reference = luminance_moments(render_moments(
            pan.scene, {"type": "path", "max_depth": 2}, REFERENCE_SPP, seed=900 + frame))
        results.append(agreement_test(mean, variance, *reference, alpha=level))
    summary = "\n".join(result.summary() for result in results)
    assert all(result.passed for result in results) != planted, summary


@pytest.mark.parametrize("disocclusions", [[], [2]])
def test_a_disocclusion_drops_the_history_at_its_frame(mi, disocclusions):
    """An animation's disocclusion at frame 2 (a static camera): frame 2's reservoirs hold
    only their own candidates (confidence M = C everywhere), frame 3's reuse them again;
    without it frame 2 reuses frame 1's (M > C). The reference of every frame is one
    (the image does not change)."""
    from renderers.integrators.restir import ReSTIRDI
    from renderers.scenes import load_scene
    from renderers.scenes.animation import Animation
    from renderers.scenes.loader import animated

    animation = Animation(disocclusions=disocclusions or [9])   # 9: after the frames shown
    scene = animated(load_scene("many-lights", 4), animation)
    restir = ReSTIRDI(scene.scene, _params(temporal=True), replicas=1)
    confidence = []
    for frame in range(4):
        scene.player.apply(frame)
        restir.render(frame)
        confidence.append(float(np.max(restir.history.reservoirs.M.numpy())))
    candidates = _params().candidates
    assert (confidence[2] == candidates) == bool(disocclusions), confidence
    assert confidence[3] > candidates
    assert len({animation.state_key(frame) for frame in range(4)}) == 1
    assert animation.change_frames() == (disocclusions or [9])
    assert animation.change_labels() == ["disocclusion"]


@pytest.mark.parametrize("frames, message", [([0], "1.."), ([3, 2], "increase strictly")])
def test_disocclusion_frames_are_validated(frames, message):
    from pydantic import ValidationError

    from renderers.scenes.animation import Animation

    with pytest.raises(ValidationError, match=message):
        Animation(disocclusions=frames)


@pytest.mark.parametrize("planted", [False, True])
def test_the_projection_follows_the_animations_camera_only(mi, monkeypatch, planted):
    """The projection is computed once per camera the animation applies: each frame of
    the pan (at 4 x 4) hands its frame the previous camera (reuse along motion vectors),
    and a frame that holds the camera computes nothing again. Planted: the animation
    player does not say that the camera changed (a stale generation): one projection,
    no motion."""
    from renderers import frozen
    from renderers.integrators import restir
    from renderers.scenes import load_scene
    from renderers.scenes.animation import Animation, CameraKey
    from renderers.scenes.loader import animated

    counts = {"projections": 0, "motions": 0}
    project, motion = restir.CameraProjection.of, restir.CameraProjection.motion

    def counted_projection(sensor):
        counts["projections"] += 1
        return project(sensor)

    def counted_motion(self):
        counts["motions"] += 1
        return motion(self)

    monkeypatch.setattr(restir.CameraProjection, "of", counted_projection)
    monkeypatch.setattr(restir.CameraProjection, "motion", counted_motion)
    if planted:
        monkeypatch.setattr(frozen, "camera_changed", lambda scene: None)
    pan = animated(load_scene("many-lights", 4), Animation(camera=[
        CameraKey(frame=0, position=(3.7, 2.7, 3.7), target=(-1.0, 0.2, -1.0)),
        CameraKey(frame=2, position=(3.2, 2.7, 3.9), target=(-1.6, 0.2, 0.2))]))
    renderer = restir.ReSTIRDI(pan.scene, _params(temporal=True), replicas=1)
    for frame in range(4):   # the camera moves until frame 2, then holds
        pan.player.apply(frame)
        renderer.render(frame)
    assert (counts == {"projections": 3, "motions": 2}) != planted, counts
