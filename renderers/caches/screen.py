"""Screen-space latent features: the position input of SS NIRC (NIRC paper Sec. 6.1).

SS NIRC gives every film pixel its own trainable latent vector in place of the
hash grid: a shading point reads the vector of the pixel it projects to through the
camera. At a primary hit that is the pixel whose sample found it, in training paths
(which start at random film positions) and render paths alike, so neither needs to
carry its pixel: the key is a function of the position. At deeper vertices the
projection names some other pixel (or none, clamped to the border): SS NIRC queries
and trains its cache at primary hits only (renderers.methods.ss_nirc).

The table is one flat Float array, ``pixels x features`` (pixel-major), trained by the
cache's Adam with the MLP. Its gradient is accumulated in fixed point like the hash
grid's (renderers.caches.grid_grad): many records of a batch hit the same pixel, and
float atomics would add them in a run-dependent order.
"""

from __future__ import annotations

import copy
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.caches.config import ScreenLatentConfig
from renderers.caches.grid_grad import (
    GridHandle,
    fixed_point_add,
    fixed_point_gradient,
    fixed_point_scale,
)


class ScreenProjection:
    """World position -> row-major film pixel of a perspective camera (the inverse of its
    ``sample_ray``: film position in [0, 1]^2 times the crop size), clamped into the
    film. Built from the scene's first sensor; other cameras are refused."""

    def __init__(self, sensor: Any) -> None:
        params = mi.traverse(sensor)
        if "x_fov" not in params or "principal_point_offset_x" not in params:
            raise ValueError("screen-space latent features need a perspective camera")
        if params["principal_point_offset_x"] != 0 or params["principal_point_offset_y"] != 0:
            raise ValueError("screen-space latent features need a camera without a "
                             "principal point offset")
        film = sensor.film()
        self.width, self.height = (int(v) for v in film.crop_size())
        to_sample = mi.perspective_projection(
            film.size(), film.crop_size(), film.crop_offset(), params["x_fov"],
            params["near_clip"], params["far_clip"])
        # Host constants (the rows x, y, w of camera-to-sample after world-to-camera): a
        # frozen training step takes no device array it was not handed.
        matrix = (np.array(to_sample.matrix).reshape(4, 4)
                  @ np.linalg.inv(np.array(params["to_world"].matrix).reshape(4, 4)))
        self.rows = [[float(v) for v in matrix[row]] for row in (0, 1, 3)]

    @property
    def pixels(self) -> int:
        return self.width * self.height

    def pixel(self, position: Any) -> mi.UInt32:
        """The pixel ``position`` projects to (row-major), clamped into the film."""
        p = mi.Point3f(position)
        x, y, w = (r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3] for r in self.rows)
        x = dr.clip(mi.Int32(dr.floor(x / w * self.width)), 0, self.width - 1)
        y = dr.clip(mi.Int32(dr.floor(y / w * self.height)), 0, self.height - 1)
        return mi.UInt32(y * self.width + x)


class LatentLookup(dr.CustomOp):
    """The ``features`` rows of ``data`` at ``pixel``; backward in fixed point."""

    def eval(self, handle: GridHandle, data: mi.Float, pixel: mi.UInt32,
             features: int) -> list[mi.Float]:
        self.handle, self.pixel, self.features = handle, pixel, features
        self.n_data = dr.width(data)
        return [dr.gather(mi.Float, data, pixel * features + k) for k in range(features)]

    def forward(self) -> None:
        raise NotImplementedError("forward-mode derivatives of the latent table are not needed")

    def backward(self) -> None:
        grad_out = list(self.grad_out())
        scale, finite = fixed_point_scale(grad_out, 1)   # one entry per lane and row
        acc = dr.zeros(dr.int64_array_t(mi.Float), self.n_data)
        for k, g in enumerate(grad_out):
            fixed_point_add(acc, g, self.pixel * self.features + k, scale)
        self.handle.finite = finite
        self.set_grad_in("data", fixed_point_gradient(acc, scale, finite))

    def name(self) -> str:
        return "LatentLookup"


class ScreenLatentEncoding:
    """Per-pixel latent features (module doc), in the interface of the hash-grid
    :class:`~renderers.caches.encodings.PositionEncoding` the cache trains and infers
    with: ``data`` (the table), :meth:`with_data`, ``n_params``, ``lookup``."""

    deterministic_grad: bool = True
    #: The handle of the last training lookup (its ``finite`` is set by backward).
    lookup: GridHandle | None = None

    def __init__(self, config: ScreenLatentConfig, projection: ScreenProjection,
                 rng: Any) -> None:
        self.config, self.projection = config, projection
        self.n_features = config.features
        size = projection.pixels * config.features
        self.data = mi.Float(rng.uniform(mi.Float, size, low=-config.init_scale,
                                         high=config.init_scale))

    @property
    def n_params(self) -> int:
        return dr.width(self.data)

    def resolutions(self) -> list[int]:
        """The film's (width, height): the table's pixels."""
        return [self.projection.width, self.projection.height]

    def with_data(self, data: mi.Float) -> ScreenLatentEncoding:
        """A copy of this encoding that reads the table ``data``."""
        other = copy.copy(self)
        other.data = data
        return other

    def encode(self, p: Any) -> list[mi.Float]:
        pixel = self.projection.pixel(p)
        if self.deterministic_grad and dr.grad_enabled(self.data):
            self.lookup = GridHandle(None)
            return list(dr.custom(LatentLookup, self.lookup, self.data, pixel,
                                  self.n_features))
        return [dr.gather(mi.Float, self.data, pixel * self.n_features + k)
                for k in range(self.n_features)]
