"""`nirc-nvc-env`: NIRC for indirect light + the environment's neural visibility cache
for its direct light (NIRC paper Sec. 4 and 5 combined).

The estimator is in renderers/integrators/nirc_nvc_env.py. Every frame trains
both caches (NIRC's training paths and step, then nvc-env's shadow rays and
step; stages ``training_paths`` and ``training`` hold both) and renders with
them; ``pretrain_frames`` trains both before the first frame.

==================  ==========  ===================================================
parameter           default     meaning
==================  ==========  ===================================================
all of `nirc`'s                 indirect light (``estimator``, ``termination``,
                                ``nc``, training, ``cache``: NIRC's cache)
env_estimator       unbiased    the environment's NEE: ``unbiased`` (cache level +
                                one-shadow-ray residual) or ``biased`` (cache level)
env_nc              7           N_c of the environment term
env_camera_points   4096        visibility training points per frame (nvc-env's
                                ``camera_points``)
env_cache           {}          overrides of nvc-env's visibility preset
==================  ==========  ===================================================

Unbiased when ``estimator`` and ``env_estimator`` both are. Applies to scenes
with an environment map and a surface.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

from pydantic import Field

from renderers.methods import nirc, register
from renderers.methods.base import FrameHooks, Method, RenderOutput
from renderers.methods.cached import (
    cache_record,
    load_integrators,
    make_cache,
    point_training,
    render_with_cache,
    scale_training_floors,
    training_stage_sizes,
)
from renderers.methods.nirc import NIRCParams
from renderers.methods.nvc_env import (
    NVCEnvParams,
    applies,
    env_visibility_config,
    visibility_cache,
)
from renderers.methods.nvc_lights import train_frame as train_env_frame
from renderers.seeding import derive_seed


class NIRCEnvParams(NIRCParams):
    """`nirc`'s parameters plus the environment term's (module docstring)."""

    env_estimator: Literal["unbiased", "biased"] = Field(
        "unbiased", description="the environment term's estimator (as nvc-env's estimator)")
    env_nc: int = Field(7, ge=1, le=64, description="N_c of the environment term")
    env_camera_points: int = Field(4096, ge=1, le=1 << 20,
                                   description="visibility training points per frame")
    env_cache: dict[str, Any] = Field(default_factory=dict,
                                      description="visibility cache config overrides")

    def cache_presets(self) -> dict[str, Any]:
        return {**super().cache_presets(), "env_cache": env_visibility_config}

    def env(self) -> NVCEnvParams:
        """The environment term's settings as `nvc-env`'s model (what its integrator and
        its ``train_frame`` read: estimator, N_c, camera points, cache overrides and
        the config parsed from them), made of these validated values as they are."""
        env = NVCEnvParams.model_construct(estimator=self.env_estimator, nc=self.env_nc,
                                           camera_points=self.env_camera_points,
                                           cache=self.env_cache)
        env._cache_configs["cache"] = self.cache_config("env_cache")
        return env


def build(scene: Any, params: NIRCEnvParams, seed: int) -> tuple[Any, Any, Any, Any]:
    """(render integrator, NIRC training integrator, NIRC cache, visibility cache)."""
    from renderers.integrators import nirc_nvc_env, register_plugins

    register_plugins()
    integrator, trainer = load_integrators(nirc_nvc_env.NIRC_NVC_ENV_PLUGIN, params,
                                           key_vertex="departure")
    env = params.env()
    visibility = visibility_cache(scene, env, derive_seed(seed, "visibility"))
    integrator.configure_env(env, visibility)
    return integrator, trainer, make_cache(scene, params.cache_config(), seed), visibility


def render(scene: Any, params: NIRCEnvParams, *, seed_parts: tuple[Any, ...], spp: int,
           frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
    """Both caches trained every frame (module docstring), then the frame rendered."""
    integrator, trainer, cache, visibility = build(scene, params,
                                                   derive_seed(*seed_parts, "cache"))
    env = params.env()
    output = render_with_cache(
        scene, params, integrator, trainer, cache, seed_parts=seed_parts, spp=spp,
        frames=frames, hooks=hooks,
        extra_training=lambda seed, timer: train_env_frame(scene, visibility, env, seed, timer),
        extra_cache=visibility)
    output.method_stats["env_cache"] = {"loss_history": list(visibility.loss_history)}
    output.method_stats["caches"]["env_cache"] = cache_record(
        visibility, point_training(visibility.config, env.camera_points))
    return output


METHOD = register(Method(
    "nirc-nvc-env", "NIRC for indirect light + a neural visibility cache for the "
                    "environment's direct light (two-level estimator)",
    NIRCEnvParams, render, version=2,
    knob=dataclasses.replace(nirc.METHOD.knob, requirement="biased nirc-nvc-env"),
    requires=applies, label="NIRC + NVC env",
    # The environment cache's training points are fixed: NIRC's records carry the growth.
    stage_sizes=training_stage_sizes, scale_floors=scale_training_floors))
