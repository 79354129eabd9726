"""Input encodings of the neural caches, identical in training and inference.

Every encoding maps Dr.Jit arrays of one SIMD width N to a list of feature
rows (``list[mi.Float]``, each of width N). That one routine serves both modes:

- inference: the list feeds ``nn.CoopVec(*rows)`` directly; it only uses
  element-wise arithmetic and gathers, so it also works inside a symbolic
  ``@dr.syntax`` loop of a Mitsuba integrator;
- training: :func:`to_tensor` stacks the rows into a ``TensorXf`` of shape
  (features, N) for the tensor-mode MLP, keeping the AD graph to the hash-grid
  parameters.

Because both modes run the same code the numbers are the same (tested).

Encodings (NIRC paper Sec. 4.4; NRC [MRNK21]):
- :class:`PositionEncoding`: multiresolution hash grid [MESK22] on the
  position normalised to [0, 1]^3 by the scene bounding box;
- :class:`SHEncoding`: real spherical harmonics of a unit direction [VHM*22];
- :class:`OneBlobEncoding`: one-blob [Müller et al. 2019, "Neural Importance
  Sampling"]: a Gaussian kernel (sigma = 1/k) centred at the value,
  discretised into k bins;
- :class:`SphericalOneBlobEncoding`: one-blob of a direction's spherical
  coordinates (NRC's direction encoding);
- :class:`IdentityEncoding`: the values themselves.
"""

from __future__ import annotations

import copy
import math
import sys
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import drjit as dr
import mitsuba as mi
from drjit import nn

from renderers.caches.config import (
    CacheConfig,
    DirectionEncodingConfig,
    HashGridConfig,
    ScalarEncodingConfig,
)
from renderers.caches.grid_grad import GridHandle, grid_lookup
from renderers.caches.screen import ScreenLatentEncoding, ScreenProjection

#: A 3-vector given as a Dr.Jit 3-array (Point3f, Vector3f, Color3f) or 3 Floats.
Vec3 = Any


def _array_xf() -> type:
    """The ``ArrayXf`` (dynamic array of Float rows) of the current variant."""
    return sys.modules[mi.Float.__module__].ArrayXf


def to_tensor(rows: Sequence[mi.Float]) -> mi.TensorXf:
    """Stack feature rows (each of width N) into a TensorXf of shape (len(rows), N).

    Rows of width 1 (constants, e.g. a uniform albedo) are broadcast to N.
    """
    n = max(dr.width(r) for r in rows)
    rows = [r if dr.width(r) == n else dr.full(mi.Float, 0.0, n) + r for r in rows]
    return mi.TensorXf(_array_xf()(*rows))


def _components(v: Vec3) -> list[mi.Float]:
    return [mi.Float(v[0]), mi.Float(v[1]), mi.Float(v[2])]


def unit_vector(d: Vec3) -> mi.Vector3f:
    """``d`` normalised; a zero vector (e.g. a masked lane) stays zero instead
    of becoming NaN, so that it cannot poison a sum it is selected out of."""
    d = mi.Vector3f(d)
    return d * dr.rsqrt(dr.maximum(dr.squared_norm(d), 1e-30))


class Encoding(ABC):
    """An input encoding: ``n_features`` rows per input (see module docstring)."""

    n_features: int

    @abstractmethod
    def encode(self, *inputs: Any) -> list[mi.Float]:
        """Inference mode: the feature rows (``nn.CoopVec(*rows)`` ready)."""

    def tensor(self, *inputs: Any) -> mi.TensorXf:
        """Training mode: the same rows as a TensorXf of shape (n_features, N)."""
        return to_tensor(self.encode(*inputs))


# --------------------------------------------------------------------------
# Simple encodings
# --------------------------------------------------------------------------

class IdentityEncoding(Encoding):
    """The ``components`` input values, unchanged."""

    def __init__(self, components: int) -> None:
        self.components = components
        self.n_features = components

    def encode(self, *values: mi.Float) -> list[mi.Float]:
        if len(values) != self.components:
            raise ValueError(f"identity encoding expects {self.components} values, "
                             f"got {len(values)}")
        return [mi.Float(v) for v in values]


def one_blob(x: mi.Float, bins: int) -> list[mi.Float]:
    """One-blob encoding of x in [0, 1] with ``bins`` bins [Müller et al. 2019].

    Bin i covers [i/k, (i+1)/k]; its value is the mass of a Gaussian of
    sigma = 1/k centred at x over the bin: Phi((b_{i+1}-x)/sigma) -
    Phi((b_i-x)/sigma). Neighbouring bins share the CDF evaluations, so k bins
    cost k+1 ``erf``. (tiny-cuda-nn replaces the Gaussian by a quartic kernel
    for speed; the encoding is computed once per shading point here, so the
    exact Gaussian costs little.)
    """
    scale = bins / math.sqrt(2.0)  # (b - x) / sigma / sqrt(2), sigma = 1/bins
    cdf = [dr.erf((i / bins - x) * scale) for i in range(bins + 1)]
    return [0.5 * (cdf[i + 1] - cdf[i]) for i in range(bins)]


class OneBlobEncoding(Encoding):
    """One-blob of each of ``components`` values in [0, 1] (``bins`` rows each)."""

    def __init__(self, components: int, bins: int) -> None:
        self.components = components
        self.bins = bins
        self.n_features = components * bins

    def encode(self, *values: mi.Float) -> list[mi.Float]:
        if len(values) != self.components:
            raise ValueError(f"one-blob encoding expects {self.components} values, "
                             f"got {len(values)}")
        rows: list[mi.Float] = []
        for v in values:
            rows += one_blob(mi.Float(v), self.bins)
        return rows


class SHEncoding(Encoding):
    """Real spherical harmonics of a unit direction: ``bands**2`` coefficients.

    NIRC paper Sec. 4.4 (4 bands in the paper, 5 in the authors' code).
    Directions are renormalised (:func:`unit_vector`) because the SH basis is
    only meaningful on the unit sphere (BSDF samples may be off by a few ulp;
    a caller's slip would otherwise silently give garbage).
    """

    def __init__(self, bands: int) -> None:
        if not 1 <= bands <= 10:
            raise ValueError(f"SH bands must be in 1..10, got {bands}")
        self.bands = bands
        self.n_features = bands * bands

    def encode(self, d: Vec3) -> list[mi.Float]:
        return [mi.Float(c) for c in dr.sh_eval(unit_vector(d), self.bands - 1)]


def spherical_unit_coordinates(d: Vec3) -> tuple[mi.Float, mi.Float]:
    """(theta / pi, phi / 2pi + 1/2) of a direction, both in [0, 1]."""
    d = unit_vector(d)
    theta = dr.safe_acos(d.z) * (1.0 / dr.pi)
    phi = dr.fma(dr.atan2(d.y, d.x), 0.5 / dr.pi, 0.5)
    return theta, phi


class SphericalOneBlobEncoding(Encoding):
    """One-blob of a direction's spherical coordinates, ``bins`` each [MRNK21]."""

    def __init__(self, bins: int) -> None:
        self.inner = OneBlobEncoding(2, bins)
        self.n_features = self.inner.n_features

    def encode(self, d: Vec3) -> list[mi.Float]:
        return self.inner.encode(*spherical_unit_coordinates(d))


# --------------------------------------------------------------------------
# Position: hash grid on the scene-normalised position
# --------------------------------------------------------------------------

class PositionEncoding(Encoding):
    """Hash grid [MESK22] over the scene bounding box mapped to [0, 1]^3.

    The box is grown by ``config.bbox_margin`` of its extent per side (so that
    points on the scene's boundary, e.g. walls, are strictly inside) and
    positions are clamped into it (a stray point outside must not wrap around
    in the integer grid coordinates).

    ``deterministic_grad`` (default True; set per instance by the cache)
    routes training lookups through :func:`renderers.caches.grid_grad.grid_lookup`,
    whose table gradient is bit-reproducible; False uses Dr.Jit's float atomics.

    The trainable table is ``grid.data`` (a flat Float array); the optimizer
    owns a copy and the cache rebinds it before every step (see
    :class:`renderers.caches.cache.NeuralCache`). :meth:`with_data` returns a
    copy reading another table (the EMA weights for inference).
    """

    deterministic_grad: bool = True
    #: The handle of the last training lookup (its ``finite`` is set by backward).
    lookup: GridHandle | None = None

    def __init__(self, config: HashGridConfig, bbox_min: Sequence[float],
                 bbox_max: Sequence[float], rng: Any) -> None:
        self.config = config
        lo = [float(v) for v in bbox_min]
        hi = [float(v) for v in bbox_max]
        if any(h < low for low, h in zip(lo, hi, strict=True)):
            raise ValueError(f"invalid bounding box: min {lo} is not <= max {hi}")
        extent = [h - low for low, h in zip(lo, hi, strict=True)]
        # A flat scene has a zero extent on one axis: give it a sliver of the
        # largest extent so the mapping stays finite.
        floor = max(max(extent), 1.0) * 1e-3
        extent = [max(e, floor) for e in extent]
        m = config.bbox_margin
        self.origin = [low - m * e for low, e in zip(lo, extent, strict=True)]
        self.inv_extent = [1.0 / ((1.0 + 2.0 * m) * e) for e in extent]
        self.grid = nn.HashGridEncoding(
            mi.Float, 3,
            n_levels=config.n_levels,
            n_features_per_level=config.n_features_per_level,
            hashmap_size=2**config.log2_hashmap_size,
            base_resolution=config.base_resolution,
            per_level_scale=config.per_level_scale,
            init_scale=config.init_scale,
            rng=rng,
        )
        self.n_features = config.n_features

    @property
    def n_params(self) -> int:
        return int(self.grid.n_params)

    @property
    def data(self) -> mi.Float:
        """The trainable table."""
        return self.grid.data

    def resolutions(self) -> list[int]:
        """Grid vertices per axis of every level (Dr.Jit's convention)."""
        return [self.grid._resolution(self.grid._level_scale(level))  # noqa: SLF001
                for level in range(self.config.n_levels)]

    def with_data(self, data: mi.Float) -> PositionEncoding:
        """A copy of this encoding that reads the table ``data``."""
        other = copy.copy(self)
        other.grid = copy.copy(self.grid)
        other.grid.data = data
        return other

    def normalise(self, p: Vec3) -> list[mi.Float]:
        """Position -> [0, 1]^3 (bounding box with margin, clamped)."""
        return [dr.clip((c - o) * s, 0.0, 1.0)
                for c, o, s in zip(_components(p), self.origin, self.inv_extent, strict=True)]

    def encode(self, p: Vec3) -> list[mi.Float]:
        u = self.normalise(p)
        if self.deterministic_grad and dr.grad_enabled(self.grid.data):
            # Training: same values, but an order-independent table gradient
            # (float atomics would make same-seed runs differ, see grid_grad).
            self.lookup = GridHandle(None)
            return list(grid_lookup(self.grid, u, self.lookup))
        return list(self.grid(u))


# --------------------------------------------------------------------------
# The composite: per-surface features + direction features
# --------------------------------------------------------------------------

def _scalar_encoding(config: ScalarEncodingConfig, components: int) -> Encoding:
    if config.kind == "oneblob":
        return OneBlobEncoding(components, config.bins)
    return IdentityEncoding(components)


def direction_encoding(config: DirectionEncodingConfig) -> Encoding | None:
    if config.kind == "sh":
        return SHEncoding(config.sh_bands)
    if config.kind == "oneblob":
        return SphericalOneBlobEncoding(config.bins)
    return None


class InputEncoder:
    """All input groups of a :class:`CacheConfig`, in the network's input order.

    The position input is the hash grid, or per-pixel latent features where the
    config has ``screen_latent`` (renderers.caches.screen; ``screen`` is then the
    camera's projection).
    :meth:`surface` encodes everything that does not depend on the query
    direction (hash grid, normal, roughness, albedos) — once per shading
    point, shared by its N_c directions (NIRC paper Sec. 4.5);
    :meth:`direction` encodes one direction.
    """

    def __init__(self, config: CacheConfig, bbox_min: Sequence[float],
                 bbox_max: Sequence[float], rng: Any, screen: ScreenProjection | None = None) -> None:
        self.config = config
        self.position: PositionEncoding | ScreenLatentEncoding
        if config.screen_latent is None:
            self.position = PositionEncoding(config.position, bbox_min, bbox_max, rng)
        elif screen is None:
            raise ValueError("a cache with screen-space latent features needs the camera's "
                             "projection (screen)")
        else:
            self.position = ScreenLatentEncoding(config.screen_latent, screen, rng)
        self.normal = None if config.normal is None else _scalar_encoding(config.normal, 3)
        self.roughness = (None if config.roughness is None
                          else _scalar_encoding(config.roughness, 1))
        self.albedo = IdentityEncoding(3) if config.albedo else None
        self.albedo_spec = IdentityEncoding(3) if config.albedo_spec else None
        self.dir = direction_encoding(config.direction)
        self.n_surface_features = config.n_surface_features
        self.n_direction_features = config.direction.n_features

    def surface(self, position: Vec3, normal: Vec3 | None = None,
                roughness: mi.Float | None = None, albedo: Vec3 | None = None,
                albedo_spec: Vec3 | None = None,
                position_encoding: PositionEncoding | ScreenLatentEncoding | None = None,
                ) -> list[mi.Float]:
        """Per-surface feature rows; ``position_encoding`` overrides the grid
        (the cache passes its inference grid here)."""
        grid = position_encoding or self.position
        rows = grid.encode(position)
        if self.normal is not None:
            n = _components(self._require(normal, "normal"))
            if isinstance(self.normal, OneBlobEncoding):
                # [-1, 1] -> [0, 1], the one-blob domain
                n = [dr.fma(c, 0.5, 0.5) for c in n]
            rows += self.normal.encode(*n)
        if self.roughness is not None:
            r = mi.Float(self._require(roughness, "roughness"))
            # 1 - exp(-r) maps [0, inf) to [0, 1) [MRNK21]
            rows += self.roughness.encode(1.0 - dr.exp(-r))
        if self.albedo is not None:
            rows += self.albedo.encode(*_components(self._require(albedo, "albedo")))
        if self.albedo_spec is not None:
            rows += self.albedo_spec.encode(
                *_components(self._require(albedo_spec, "albedo_spec")))
        return rows

    def direction(self, d: Vec3 | None) -> list[mi.Float]:
        """Direction feature rows (empty when the config has no direction input)."""
        if self.dir is None:
            return []
        return self.dir.encode(self._require(d, "direction"))

    @staticmethod
    def _require(value: Any, name: str) -> Any:
        if value is None:
            raise ValueError(f"this cache's config encodes '{name}' but no {name} was given")
        return value
