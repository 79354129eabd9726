"""Neural control variate of the first hits' shading integrand [Müller et al. 2020,
"Neural Control Variates" (NCV)], as the NIRC paper configured it (Sec. 6.1): a
normalised shape q_c (renderers.caches.flow, one flow per colour channel) times an
integral G_c predicted by a second network sharing the input encoding,

    g_c(w) = G_c q_c(w),      int_S2 g_c dw = G_c,

so G_c is the control variate's closed-form integral (NIRC Eq. 7).

**Inputs.** The estimator's models are per pixel (renderers.integrators.control_variate:
g_p may depend on the pixel, never on the sampled w), so both networks are conditioned
on the surface seen through the pixel's centre (a G-buffer traced once): its position
through NIRC's multiresolution hash grid and its shading normal one-blob encoded, as
NIRC's cache encodes them (renderers.caches.encodings). The flow works in the frame of
that normal (the hemisphere above it is u_1 > 1/2).

**Training** (between frames, on the frame's samples; docs/ncv.md). With a sample w_j
of density p_j = q_mix(w_j) and the estimate f_j of the integrand, the residual of the
estimate G + (f - g)/p is r_j = f_j/p_j - G_c q_c(w_j)/p_j, and one Adam step
minimises its second moment,

    E[r^2] = V[G + (f - g)/p] + (F - G)^2,                                (NCV Eq. 6)

the estimator's variance plus the integral's squared error, estimated by the batch
mean of r_j^2 / (sg(G_c)^2 + eps) (sg: no gradient; each pixel's weight makes the
loss scale-invariant, as NIRC's Eq. 18). Its gradient trains the shape and the
integral at once through the product g = G q.

A step whose loss or any gradient is not finite is skipped (Adam's weights and moments
left as they were): a finite loss can still have a non-finite gradient, and one such
step writes NaN into the weights, after which g and every later loss are NaN (on sky
16x16, version 1: the 76th step, its loss 21.8, left NaN in a coupling MLP once the
flow's bins were ~1e-27 wide). Skipping a step changes only which g the next frames
use, so the estimate stays unbiased; the flow's floor (renderers.caches.flow,
``uniform_mix``) keeps the bins from collapsing in the first place.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
from drjit import nn
from drjit.opt import Adam
from pydantic import BaseModel, ConfigDict, Field

from renderers.caches.config import HashGridConfig
from renderers.caches.encodings import OneBlobEncoding, PositionEncoding
from renderers.caches.flow import FlowConfig, SphereFlow, network_rows
from renderers.seeding import derive_seed

CHANNELS = 3
#: The optimizer's key of the hash-grid table (the others are the networks' keys).
GRID_KEY = "position.hashgrid"


class NCVConfig(BaseModel):
    """The neural control variate (module docstring) and its online training."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    flow: FlowConfig = Field(default_factory=FlowConfig)
    position: HashGridConfig = Field(
        default_factory=lambda: HashGridConfig(n_levels=12, n_features_per_level=2,
                                               log2_hashmap_size=16, base_resolution=16,
                                               per_level_scale=1.5),
        description="hash grid of the pixel's surface position (NIRC's preset)")
    normal_bins: int = Field(4, ge=1, le=64, description="one-blob bins per normal component")
    integral_width: int = Field(64, ge=1, le=1024)
    integral_hidden_layers: int = Field(5, ge=1, le=16,
                                        description="hidden layers of the G network (NRC's 5)")
    batch_size: int = Field(4096, ge=1, le=1 << 20,
                            description="samples per Adam step (the paper: 57,600)")
    steps_per_frame: int = Field(1, ge=0, le=64, description="Adam steps per frame")
    learning_rate: float = Field(5e-3, gt=0.0)
    epsilon: float = Field(1e-2, gt=0.0, description="eps of the loss's sg(G)^2 + eps")

    @property
    def n_condition(self) -> int:
        return self.position.n_levels * self.position.n_features_per_level \
            + 3 * self.normal_bins


def ncv_config(**overrides: Any) -> NCVConfig:
    """The NCV preset with ``overrides`` (a method's ``ncv`` parameter)."""
    return NCVConfig(**overrides)


def centre_rays(scene: mi.Scene, index: mi.UInt32) -> mi.Ray3f:
    """The camera rays through the centres of the pixels ``index`` (the render's pixel
    index: row-major over the film's crop window)."""
    sensor = scene.sensors()[0]
    film = sensor.film()
    width = int(film.crop_size()[0])
    centre = (mi.Vector2f(mi.Float(index % width), mi.Float(index // width)) + 0.5
              + mi.Vector2f(film.crop_offset())) / mi.Vector2f(film.size())
    ray, _ = sensor.sample_ray(0.0, 0.5, centre, mi.Point2f(0.5))
    return ray


def pixel_surfaces(scene: mi.Scene) -> tuple[mi.Point3f, mi.Vector3f, mi.Bool]:
    """Position, shading normal and hit of the ray through each pixel's centre, in the
    order of the render's pixel index (row-major over the film's crop window)."""
    width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
    si = scene.ray_intersect(centre_rays(scene, dr.arange(mi.UInt32, width * height)))
    hit = si.is_valid()
    normal = dr.select(hit, si.sh_frame.n, mi.Vector3f(0, 0, 1))
    return dr.select(hit, si.p, 0.0), normal, hit


def integral_mlp(config: NCVConfig) -> nn.Sequential:
    layers: list[nn.Module] = []
    for _ in range(config.integral_hidden_layers):
        layers += [nn.Linear(-1, config.integral_width), nn.ReLU()]
    layers.append(nn.Linear(-1, CHANNELS))
    return nn.Sequential(*layers)


class NCVModel:
    """g_p = G_p q_p per pixel from two networks on the pixel's surface (module
    docstring). G starts at 0 (the output layer of its network is zero): the first
    frame is the plain estimator. Frames are not frozen (``freezable``)."""

    freezable = False

    def __init__(self, config: NCVConfig, scene: mi.Scene, seed: int = 0) -> None:
        self.config = config
        self.seed = int(seed)
        self.positions, self.normals, self.hits = pixel_surfaces(scene)
        self.pixels = dr.width(self.hits)
        bbox = scene.bbox()
        self.position = PositionEncoding(config.position, list(bbox.min), list(bbox.max),
                                         dr.rng(derive_seed(self.seed, "hashgrid")))
        self.normal_encoding = OneBlobEncoding(3, config.normal_bins)
        self.flow = SphereFlow(config.flow, config.n_condition, derive_seed(self.seed, "flow"))
        self.integral_net = integral_mlp(config).alloc(
            mi.TensorXf, config.n_condition, rng=dr.rng(derive_seed(self.seed, "integral")))
        last = self.integral_net.layers[-1]
        last.weights, last.bias = dr.zeros(mi.TensorXf, last.weights.shape), \
            dr.zeros(mi.TensorXf, last.bias.shape)
        dr.make_opaque(last.weights, last.bias)   # literal zeros would compile other kernels
        self.optimizer = Adam(lr=config.learning_rate, beta_1=0.9, beta_2=0.99)
        for key, value in self._parameters().items():
            self.optimizer[key] = value
        self.steps = 0
        self.skipped_steps = 0
        self.samples_trained = 0
        self.nonfinite = 0
        self.loss_history: list[float] = []
        self._refresh()

    # ---- parameters ----
    def _parameters(self) -> dict[str, Any]:
        return {**self.flow.parameters(),
                **{f"integral.{key}": value for key, value in self.integral_net.items()},
                GRID_KEY: self.position.grid.data}

    def _bind(self) -> None:
        """Read the optimizer's values (Adam owns the parameters)."""
        self.flow.bind(self.optimizer)
        for key in list(self.integral_net.keys()):
            self.integral_net[key] = self.optimizer[f"integral.{key}"]
        self.position = self.position.with_data(self.optimizer[GRID_KEY])

    def parameter_count(self) -> dict[str, int]:
        counts = {"flow": 0, "integral": 0, "hashgrid": self.position.n_params}
        for key, value in self._parameters().items():
            if key != GRID_KEY:
                counts[key.split(".")[0]] += dr.width(value.array)
        return counts

    # ---- evaluation ----
    def condition(self, position: mi.Point3f, normal: mi.Vector3f) -> list[mi.Float]:
        """The networks' input rows: hash grid of the position, one-blob of the normal."""
        return self.position.encode(position) + self.normal_encoding.encode(
            *(dr.fma(normal[i], 0.5, 0.5) for i in range(3)))

    def shape_density(self, w: mi.Vector3f, normal: mi.Vector3f,
                      condition: list[mi.Float]) -> list[mi.Float]:
        """q_c(w) per channel, w in the frame of ``normal``."""
        return self.flow.sphere_density(mi.Frame3f(normal).to_local(w), condition)

    def _refresh(self) -> None:
        """Each pixel's condition rows and G, read by the renders until the next fit."""
        self._bind()
        with dr.suspend_grad():
            self.pixel_condition = self.condition(self.positions, self.normals)
            dr.eval(self.pixel_condition)
            integral = network_rows(self.integral_net, self.pixel_condition)
            self.pixel_integral = [dr.select(self.hits, g, 0.0) for g in integral]
            dr.eval(self.pixel_integral)

    def integral(self, pixel: mi.UInt32, active: mi.Bool) -> mi.Spectrum:
        """G_p per channel."""
        return mi.Spectrum(*(dr.gather(mi.Float, g, pixel, active)
                             for g in self.pixel_integral))

    def eval(self, pixel: mi.UInt32, w: mi.Vector3f, active: mi.Bool) -> mi.Spectrum:
        """g_p(w) = G_p q_p(w) per channel."""
        condition = [dr.gather(mi.Float, row, pixel, active) for row in self.pixel_condition]
        normal = dr.gather(mi.Vector3f, self.normals, pixel, active)
        density = self.shape_density(w, normal, condition)
        return dr.select(active, self.integral(pixel, active) * mi.Spectrum(*density), 0.0)

    # ---- training ----
    def fit(self, records: Any) -> None:
        """``steps_per_frame`` Adam steps on batches of the render's samples that
        produced a direction (module docstring), then the pixels' G and inputs anew."""
        self.nonfinite += records.nonfinite_count()
        usable = np.flatnonzero(np.asarray(records.pdf) > 0)
        rng = np.random.default_rng(derive_seed(self.seed, "batches", self.steps
                                                + self.skipped_steps))
        for _ in range(self.config.steps_per_frame):
            if usable.size == 0:
                break
            chosen = np.sort(rng.choice(usable, min(usable.size, self.config.batch_size),
                                        replace=False))
            self._step(records, mi.UInt32(chosen))
        self._refresh()

    def _step(self, records: Any, lanes: mi.UInt32) -> None:
        self._bind()
        pixel = lanes // records.spp
        w = dr.gather(mi.Vector3f, records.w, lanes)
        pdf = dr.gather(mi.Float, records.pdf, lanes)
        weighted = dr.gather(mi.Spectrum, records.weighted, lanes)
        normal = dr.gather(mi.Vector3f, self.normals, pixel)
        condition = self.condition(dr.gather(mi.Point3f, self.positions, pixel), normal)
        integral = network_rows(self.integral_net, condition)
        density = self.shape_density(w, normal, condition)
        loss = mi.Float(0.0)
        for c in range(CHANNELS):
            residual = weighted[c] - integral[c] * density[c] / pdf
            loss += dr.mean(dr.square(residual)
                            / (dr.square(dr.detach(integral[c])) + self.config.epsilon))
        dr.backward(loss)
        finite = self._finite(loss)
        self.optimizer.step(active=finite)   # a masked step leaves weights and moments
        value = float(loss[0])
        if not bool(finite[0]):
            self.skipped_steps += 1
            return
        self.steps += 1
        self.samples_trained += dr.width(lanes)
        self.loss_history.append(value)

    def _finite(self, loss: mi.Float) -> mi.Bool:
        """One flag: the loss and every parameter's gradient are finite (any non-finite
        entry scatters False into it)."""
        finite = dr.opaque(mi.Bool, True, 1)
        for value in [loss, *(dr.grad(self.optimizer[key]).array for key in self.optimizer)]:
            dr.scatter(finite, False, 0, active=~dr.isfinite(value),
                       mode=dr.ReduceMode.NoConflicts)
        dr.eval(finite)
        return finite

    def stats(self) -> dict[str, Any]:
        """What a run stores of the model: config, parameters, floats per pixel (the
        per-pixel buffers, and the parameters shared per pixel), training progress."""
        parameters = self.parameter_count()
        per_pixel = {"surface": 6, "condition": self.config.n_condition, "integral": CHANNELS}
        return {"config": self.config.model_dump(mode="json"),
                "parameters": parameters,
                "floats_per_pixel": {
                    "model": sum(per_pixel.values())
                    + sum(parameters.values()) / max(self.pixels, 1),
                    "per_pixel_buffers": per_pixel},
                "steps": self.steps, "skipped_steps": self.skipped_steps,
                "samples_trained": self.samples_trained,
                "nonfinite_samples": self.nonfinite,
                "last_loss": self.loss_history[-1] if self.loss_history else None}
