"""What a method's parameters add to the work of a render (jobs/execution/work.py).

A seed renders ``frames + warm_frames`` frames (``warm_frames``: the pre-training
or pre-fill frames the method renders before its timed ones), each counted as

    samples per frame = pixels x spp x path_factor + training + points

* ``path_factor`` bounds what one path sample costs relative to the defaults'. Its
  depth: Russian roulette after ``rr_depth`` bounces with survival ``q`` makes the
  expected length at most ``rr_depth + 1 / (1 - q)`` bounces (the geometric tail),
  capped by ``max_depth``; a caching method's termination (NIRC paper, Sec. 4; its
  ``sph_c`` and policy parameters) only ever ends a path *earlier* than that, so its
  parameters are not counted. Then the work each sample multiplies, each relative to
  its default: ReSTIR's initial candidates and spatial neighbours (one reservoir
  each), a light cluster's candidates, the cache directions per vertex (N_c), the
  vertices recorded per training path, the hits a grid cache stores.
* ``training``: the method's stage sizes (``Method.stage_sizes``, the units of the
  per-stage cost model, jobs/costs/cost_model.py): training paths and records of a
  frame, with the training budget's rule, floors and cap.
* ``points``: the points a frame trains or shades whatever its size (a visibility
  cache's world and camera points).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

from renderers.methods import METHODS

#: Bounces counted for a path that only ends by escaping the scene (no ``max_depth``,
#: no roulette): in a closed scene it has no bound at all.
UNBOUNDED_BOUNCES = 1024.0
#: Frames a method renders before its timed ones.
WARM_FRAME_PARAMS = ("pretrain_frames", "prefill_frames")
#: Work per path sample, relative to the parameter's default.
PER_SAMPLE_PARAMS = ("candidates", "cluster_candidates", "nc", "env_nc", "record_depth")
#: Work a sample adds besides its own path (neighbours it visits, hits it stores with a
#: probability): (1 + value) relative to (1 + default).
EXTRA_PER_SAMPLE_PARAMS = ("spatial_neighbours", "hit_store_probability")
#: Points trained or shaded in every frame.
POINT_PARAMS = ("world_points", "camera_points", "env_camera_points", "clusters")


@dataclass(frozen=True)
class FrameWork:
    """Path samples per frame and frames per seed of one render's method parameters."""

    samples_per_frame: float
    warm_frames: int


def path_length(params: Any) -> float:
    """The bound on a path's expected bounces (module doc): without ``max_depth`` and
    roulette (survival 1), :data:`UNBOUNDED_BOUNCES`."""
    max_depth = getattr(params, "max_depth", -1)
    limit = float(max_depth) if max_depth > 0 else UNBOUNDED_BOUNCES
    rr_depth = getattr(params, "rr_depth", None)
    survival = getattr(params, "rr_survival", 1.0)
    if rr_depth is None or survival >= 1.0:
        return limit
    return min(limit, rr_depth + 1.0 / (1.0 - survival))


def path_factor(params: Any, defaults: Any) -> float:
    """What a path sample of ``params`` costs relative to one of ``defaults``."""
    factor = path_length(params) / path_length(defaults)
    for name in PER_SAMPLE_PARAMS:
        if isinstance(getattr(defaults, name, None), int):
            factor *= getattr(params, name) / getattr(defaults, name)
    for name in EXTRA_PER_SAMPLE_PARAMS:
        if hasattr(defaults, name):
            factor *= (1 + getattr(params, name)) / (1 + getattr(defaults, name))
    return factor


@cache
def _defaults(method_name: str) -> Any:
    """The method's default parameters, built without validating (they are the model's
    own defaults): a job's parameters are validated once, where it enters."""
    return METHODS[method_name].params.model_construct()


def frame_work(method_name: str, params: Any, pixels: int, spp: int) -> FrameWork:
    """Samples per frame and warm frames of ``method_name`` with ``params`` (its
    parameter model); an unknown method counts pixels x spp."""
    method = METHODS.get(method_name)
    if method is None:
        return FrameWork(float(pixels * spp), 0)
    samples = pixels * spp * path_factor(params, _defaults(method_name))
    samples += sum(method.stage_sizes(params, pixels, spp).values())
    samples += sum(getattr(params, name, 0) for name in POINT_PARAMS)
    return FrameWork(samples, sum(getattr(params, name, 0) for name in WARM_FRAME_PARAMS))
