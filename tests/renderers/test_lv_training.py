"""Training data of the variance-based loss L_V (NIRC paper Eq. 16): groups of training
paths share their first vertex (F_r's samples), and the cache keeps groups whole."""

from __future__ import annotations

from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from renderers.caches import TrainingRecords
from renderers.methods import nirc, parse_params

pytestmark = pytest.mark.usefixtures("mi")
GROUP = 8


def build(**params):
    scene = mi.load_dict(mi.cornell_box())
    _integrator, trainer, cache = nirc.build(SimpleNamespace(scene=scene, resolution=(16, 16)),
                                             parse_params("nirc", params), seed=3)
    return scene, trainer, cache


def groups_share_their_first_vertex(records: dict, paths: int) -> tuple[bool, bool]:
    """(positions equal within every group, directions all distinct within groups)."""
    position = np.asarray(records["position"]).T.reshape(paths // GROUP, GROUP, 3)
    direction = np.asarray(records["direction"]).T.reshape(paths // GROUP, GROUP, 3)
    valid = np.asarray(records["valid"]).reshape(paths // GROUP, GROUP).all(axis=1)
    same = bool(np.all(position[valid] == position[valid][:, :1]))
    distinct = all(len(np.unique(d, axis=0)) == GROUP for d in direction[valid])
    return same, distinct


def test_lv_training_paths_come_in_groups_through_one_first_vertex() -> None:
    scene, trainer, _cache = build(loss="variance", record_depth=1,
                                   cache={"loss": {"group_size": GROUP}})
    records = trainer.trace_records(scene, 61, 5)   # rounded up to whole groups
    assert dr.width(records["valid"]) == 64
    assert groups_share_their_first_vertex(records, 64) == (True, True)
    # Planted: groups misaligned by one path (each straddles two film positions) fail.
    shifted = {name: dr.gather(type(value), value, (dr.arange(mi.UInt32, 64) + 1) % 64)
               for name, value in records.items()}
    assert not groups_share_their_first_vertex(shifted, 64)[0]


def test_the_cache_drops_and_draws_whole_groups() -> None:
    n = 4 * GROUP
    rng = np.random.default_rng(0)
    valid = np.ones(n, bool)
    valid[GROUP + 3] = False   # one record of the second group unusable
    records = TrainingRecords(
        position=mi.Point3f(*rng.uniform(-0.5, 0.5, (3, n))), target=mi.Color3f(*rng.uniform(0, 1, (3, n))),
        normal=mi.Vector3f(0, 0, 1), roughness=mi.Float(1.0), albedo=mi.Color3f(0.5),
        direction=mi.Vector3f(0, 0, 1), valid=mi.Bool(valid))
    for params, kept in (({"loss": "variance", "record_depth": 1,
                           "cache": {"loss": {"group_size": GROUP}}}, n - GROUP),
                         ({}, n - 1)):   # planted: per record, only the bad one goes
        _scene, _trainer, cache = build(**params)
        assert dr.width(cache._usable_indices(records)) == kept
    _scene, _trainer, cache = build(loss="variance", record_depth=1,
                                    cache={"loss": {"group_size": GROUP}})
    for draw in cache._batch_indices(n, 2 * GROUP, 5, GROUP):
        runs = draw.reshape(2, GROUP)
        assert np.all(runs % GROUP == np.arange(GROUP)) and np.all(np.diff(runs) == 1)
