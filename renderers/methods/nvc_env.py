"""`nvc-env`: direct environment light through a neural visibility cache.

NIRC paper, Sec. 5 (Fig. 11): at every shading vertex the environment's
next-event estimation becomes a two-level estimator whose first level is
N_c directions from the environment's importance sampling weighted by the
visibility V_c(x, w) a neural cache predicts (no shadow rays), and whose
second level (``estimator='unbiased'``) is one shadow-ray sample of
V - V_c; other emitters and indirect light are the PT core's
(:mod:`renderers.integrators.nvc_env`, docs/estimators.md "nvc-env").

Every frame first trains the cache (one Adam step on the shadow-ray outcomes
of ``camera_points`` camera first hits and as many second vertices, stage
``training_paths`` for the rays, ``training`` for the step), then renders
with it; ``pretrain_frames`` frames of training may come first.

==================  ==========  ===================================================
parameter           default     meaning
==================  ==========  ===================================================
max_depth, rr_*     as `pt`     the PT core
estimator           unbiased    ``unbiased``: cache level + residual with one shadow
                                ray (NIRC Eq. 10-12); ``biased``: the cache level
                                alone (Eq. 13)
nc                  7           N_c, cache directions per vertex (NIRC Fig. 11)
target              visibility  what the cache predicts: ``visibility`` V(x, w) (the
                                NVC); ``radiance``: the RGB incident light
                                L_env(w) V(x, w), NIRC's inputs and loss, 2 hidden
                                layers (NIRC predicting the same direct light, the
                                NIRC paper's Fig. 11; ``env_radiance_config``)
camera_points       4096        training points per frame: camera first hits, plus
                                as many vertices one cosine bounce further
pretrain_frames     0           training frames before the first (warm-up) frame
cache               {}          overrides of the cache preset
                                (``renderers.caches.visibility_config`` with one
                                output and NIRC's direction encoding, SH 5 bands:
                                hash grid 10 levels x 4 features; MLP 2 x 32;
                                sigmoid; L2; Adam lr 0.05 -> 0.001 over 200
                                steps; batch 8192, 1 step per frame)
==================  ==========  ===================================================

The training budget is the visibility preset's (``cache.batch_size`` x
``cache.steps_per_frame`` records per frame), not the radiance caches'
``CacheTrainingParams``: the records are shadow rays, not training paths.
Applies to scenes with an environment map (``SceneFeatures.has_envmap``) and
a surface.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

from pydantic import Field

from renderers.methods import register
from renderers.methods.base import Knob, Method, fixed_stages
from renderers.methods.cached import has_surface, make_cache
from renderers.methods.nvc_lights import train_frame, visibility_cache_render
from renderers.methods.pt import SPP_CANDIDATES, PTParams

#: NIRC's direction encoding (nirc_config): spherical harmonics, 5 bands.
DIRECTION_ENCODING = {"kind": "sh", "sh_bands": 5}


class NVCEnvParams(PTParams):
    """The PT core's parameters plus the estimator's and the cache's (module docstring)."""

    estimator: Literal["unbiased", "biased"] = Field(
        "unbiased", description="'unbiased': cache level + residual with one shadow ray "
                                "(NIRC Eq. 10-12); 'biased': the cache level alone (Eq. 13)")
    nc: int = Field(7, ge=1, le=64, description="cache directions per vertex (N_c)")
    target: Literal["visibility", "radiance"] = Field(
        "visibility", description="the cache predicts V(x, w) or the radiance L_env V (RGB)")
    camera_points: int = Field(4096, ge=1, le=1 << 20,
                               description="training camera first hits per frame")
    pretrain_frames: int = Field(0, ge=0, le=100_000,
                                 description="training frames before the first (warm-up) frame")
    cache: dict[str, Any] = Field(default_factory=dict, description="cache config overrides")

    def core(self) -> dict[str, Any]:
        """The PT core's plugin properties."""
        return self.model_dump(include=set(PTParams.model_fields))

    def cache_preset(self) -> Callable[..., Any]:
        """The preset of the cache ``target`` asks for."""
        return env_visibility_config if self.target == "visibility" else env_radiance_config

    def cache_presets(self) -> dict[str, Any]:
        return {"cache": self.cache_preset()}


def env_visibility_config(**overrides: Any) -> Any:
    """The visibility preset with one output and NIRC's direction encoding."""
    from renderers.caches import visibility_config

    return visibility_config(1, **{"direction": DIRECTION_ENCODING, **overrides})


def env_radiance_config(**overrides: Any) -> Any:
    """NIRC's cache (inputs, output, loss, optimizer) with 2 hidden layers, as the NIRC
    paper's Fig. 11 limits both networks, trained on the visibility cache's records
    (``batch_size`` 8192, 1 step per frame) so that both learn from the same data."""
    from renderers.caches import nirc_config

    return nirc_config(**{"mlp": {"hidden_layers": 2}, "batch_size": 8192,
                          "steps_per_frame": 1, **overrides})


def build(scene: Any, params: NVCEnvParams, seed: int) -> tuple[Any, Any]:
    """(integrator, cache): the PT core with the env-NEE estimator, untrained."""
    import mitsuba as mi

    from renderers.integrators import nvc_env, register_plugins

    register_plugins()
    cache = visibility_cache(scene, params, seed)
    integrator = mi.load_dict({"type": nvc_env.NVC_ENV_PLUGIN, **params.core()})
    integrator.configure(params, cache)
    return integrator, cache


def visibility_cache(scene: Any, params: NVCEnvParams, seed: int) -> Any:
    """A new cache of ``params.target`` carrying its frame's training records
    (``cache.training_records``, frozen where freezing is on), which the visibility
    caches' ``train_frame`` (renderers.methods.nvc_lights) reads."""
    from renderers.integrators.nvc_env import EnvVisibilityRecords

    cache = make_cache(scene, params.cache_config(), seed)
    cache.training_records = EnvVisibilityRecords(params.camera_points, params.target)
    return cache


render = visibility_cache_render(build, train_frame)


def applies(features: Any) -> tuple[bool, str]:
    """An environment map to cache the visibility of, and a surface for the cache."""
    if not features.has_envmap:
        return False, "no environment map"
    return has_surface(features)


METHOD = register(Method("nvc-env",
                "direct environment light as a two-level estimator: N_c env-map samples "
                "weighted by a neural visibility cache + a one-shadow-ray residual",
                NVCEnvParams, render, version=2,
                requires=applies, label="NVC env", knob=Knob("spp", SPP_CANDIDATES),
                stage_sizes=fixed_stages("training_paths", "training")))
