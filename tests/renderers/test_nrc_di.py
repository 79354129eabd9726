"""`nrc-di` (renderers.integrators.nrc_di): a neural cache of the direct light at primary hits.

Registration and ``applies_to`` reasons; the training records (surface points,
non-negative one-sample NEE targets); and on a trivial scene (a floor under
one rectangle light, 16 x 16, reference Mitsuba's ``path`` at max_depth 2):
the MRSE of the prediction falls with training frames (measured 0.098 after 8
frames, 0.0012 after 64) and is small after 64 frames. Planted: training
targets a factor π too large (a BRDF missing its 1/π) leave a large error, so
the small-error check can fail.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from metrics.errors import mrse
from tests.renderers.scene_xml import perspective_sensor

RES = 16
TRAIN_FRAMES = 64

FLOOR_AND_LIGHT = """<scene version="3.0.0">
    """ + perspective_sensor("50", "0, 3, 3", "0, 0, 0") + """
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/>
            <translate y="1.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="10, 9, 8"/></emitter>
    </shape>
</scene>
"""


@pytest.fixture(scope="module")
def trivial(mi):
    scene = mi.load_string(FLOOR_AND_LIGHT.format(res=RES))
    reference = np.asarray(mi.render(scene, integrator=mi.load_dict(
        {"type": "path", "max_depth": 2}), spp=4096, seed=1))[..., :3]
    return SimpleNamespace(scene=scene, resolution=(RES, RES)), reference


def _errors(mi, scene, reference, checkpoints) -> dict[int, float]:
    """MRSE of the prediction (16 spp: the pixel footprint) after each checkpoint's
    number of training frames."""
    from renderers.methods.nrc_di import NRCDIParams, build, train_frame
    from renderers.timing import StageTimer

    params = NRCDIParams()
    integrator, cache = build(scene, params, 0)
    errors = {}
    for frame in range(max(checkpoints) + 1):
        if frame in checkpoints:
            image = np.asarray(mi.render(scene.scene, integrator=integrator, spp=16,
                                         seed=frame))[..., :3]
            errors[frame] = mrse(image, reference)
        train_frame(scene, cache, params, frame, StageTimer())
    print("MRSE after frames:", {f: round(e, 5) for f, e in errors.items()})
    return errors


def test_registered_with_a_fixed_depth_and_the_visibility_network():
    from renderers.caches import direct_light_config, visibility_config
    from renderers.methods import METHODS, MethodError, parse_params

    assert parse_params("nrc-di", {}).max_depth == 2
    with pytest.raises(MethodError, match="max_depth"):
        parse_params("nrc-di", {"max_depth": 3})
    assert METHODS["nrc-di"].version == 2
    config, nvc = direct_light_config(), visibility_config(3)
    assert (config.position, config.mlp, config.optimizer) == (nvc.position, nvc.mlp,
                                                               nvc.optimizer)
    assert (config.output.n_outputs, config.output.activation) == (3, "clamped_linear")


@pytest.mark.parametrize(("shapes", "emitters", "reason"), [
    (0, 1, "the scene has no surface to shade"),
    (3, 0, "no emitter"),
    (3, 40, ""),
])
def test_applies_to_states_why_not(shapes, emitters, reason):
    from renderers.methods import METHODS

    features = SimpleNamespace(shape_count=shapes, emitter_count=emitters)
    assert METHODS["nrc-di"].applies_to(features) == (not reason, reason)


def test_training_records_are_surface_points_with_direct_light_targets(mi, trivial):
    from renderers.integrators.nrc_di import direct_light_records

    scene, _ = trivial
    records = direct_light_records(scene.scene, 512, 512, seed=3)
    target = np.stack([t.numpy() for t in records.target_rows()])
    valid = records.valid.numpy()
    assert target.shape == (3, 1024) and np.all(target >= 0)
    assert valid[512:].mean() > 0.5                    # the camera sees the floor
    assert np.all(np.abs(records.position.y.numpy()[valid]) < 1.6)  # on the floor or light
    assert target[:, valid].mean() > 0


@pytest.mark.slow
def test_error_falls_with_training_and_ends_small(mi, trivial):
    errors = _errors(mi, *trivial, checkpoints=(8, TRAIN_FRAMES))
    assert errors[TRAIN_FRAMES] < 0.1 * errors[8]
    assert errors[TRAIN_FRAMES] < 0.01


@pytest.mark.slow
def test_planted_targets_without_the_brdfs_one_over_pi_leave_a_large_error(mi, trivial,
                                                                            monkeypatch):
    from renderers.integrators import nrc_di

    records = nrc_di.DirectLightRecords.records

    def planted(self, *args):
        r = records(self, *args)
        r.target = r.target * math.pi
        return r

    monkeypatch.setattr(nrc_di.DirectLightRecords, "records", planted)
    errors = _errors(mi, *trivial, checkpoints=(TRAIN_FRAMES,))
    assert errors[TRAIN_FRAMES] > 0.01
