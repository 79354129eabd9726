"""Per-pixel mixture of von Mises-Fisher lobes, a control variate with a closed-form
integral (NIRC paper Sec. 6.1: 11 lobes of 7 coefficients, directions initialised on
a spherical Fibonacci lattice, fitted by stepwise EM [VKS*14]).

Lobe k of pixel p: mean direction mu_k (3 floats), concentration kappa_k (1) and an
amplitude a_kc per colour channel (3): 7 floats per lobe, 77 per pixel at 11 lobes.
With the normalised vMF density

    v(w; mu, kappa) = kappa / (2 pi (1 - exp(-2 kappa))) exp(kappa (mu.w - 1)),
    int_S2 v dw = 1,

the model and its closed-form integral over the sphere are

    g_pc(w) = sum_k a_kc v(w; mu_k, kappa_k),        G_pc = sum_k a_kc.

Fitting: stepwise EM over weighted samples (Vorba et al. 2014, Sec. 4-5). A sample
w_j of the pixel, drawn with density q, with integrand estimate f_jc carries the
weights o_jc = f_jc / q(w_j) (their channel mean o_j for the shape). With mixture
weights pi_k proportional to the amplitudes' channel mean (the same statistic),

    E-step:  gamma_jk = pi_k v_k(w_j) / sum_l pi_l v_l(w_j)      (current lobes)
    batch:   A_kc = 1/N sum_j o_jc gamma_jk,   S_k = 1/N sum_j o_j gamma_jk w_j
    step:    a <- (1 - eta_t) a + eta_t A,   s <- (1 - eta_t) s + eta_t S,
             eta_t = (t + 1)^(-step_exponent), t the pixel's batches so far
    M-step:  mu_k = s_k / |s_k|,  rbar = |s_k| / mean_c a_kc  n_k / (n_k + nu),
             kappa_k = rbar (3 - rbar^2) / (1 - rbar^2)   (Banerjee et al. 2005)

The M-step's mean length is a MAP estimate, not Vorba et al.'s maximum likelihood:
a prior of nu pseudo-samples (``prior_samples``) of zero resultant, each carrying
the lobe's mean weight, shrinks the data's rbar by n_k / (n_k + nu), n_k the
lobe's effective sample count: Kish's (sum_j o_j gamma_jk)^2 / sum_j (o_j
gamma_jk)^2 of each batch, summed over the batches. Without it (nu = 0) a lobe fed
by one sample has rbar = 1 and kappa at its bound 1e4: g then puts the lobe's
whole amplitude where the next frames' samples almost never go, so a frame's
estimate is G - a_k too high unless a rare sample reaches the lobe and repays it
at once (unbiased, but so heavy-tailed that the means of a few seeds were biased:
docs/control_variates.md). With the prior kappa grows about as n_k / nu.

so a_kc estimates int f_c gamma_k and sum_k a_kc estimates int f_c. One batch is
one frame's samples of the pixel (its spp first hits), which the render keeps
(renderers.integrators.control_variate_records) and :meth:`VMFModel.fit` folds in
between frames, its E-step under the lobes that frame rendered with: a frame's g
never depends on its own samples. The first batch (eta_0 = 1) replaces the initial amplitudes, which are 0
(g = 0: the plain estimator) until then.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

CHANNELS = 3
#: Floats per lobe of the model: mean direction (3), concentration (1), amplitude (3).
LOBE_FLOATS = 7
#: Bounds of kappa: below, the lobe is uniform to float precision; above, a lobe
#: narrower than float32 directions resolve.
KAPPA_RANGE = (1e-3, 1e4)


class VMFConfig(BaseModel):
    """The per-pixel vMF mixture (module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lobes: int = Field(11, ge=1, le=64, description="vMF lobes per pixel")
    initial_kappa: float = Field(5.0, ge=KAPPA_RANGE[0], le=KAPPA_RANGE[1],
                                 description="concentration of every lobe before the fit")
    step_exponent: float = Field(0.7, gt=0.5, le=1.0,
                                 description="stepwise EM's rate eta_t = (t+1)^-exponent")
    prior_samples: float = Field(1.0, ge=0.0, le=1e6,
                                 description="pseudo-samples of zero mean resultant in "
                                             "kappa's MAP estimate (0: maximum likelihood)")

    def floats_per_pixel(self) -> dict[str, int]:
        """The model's floats per pixel (what g is), and the fit's: the running mean
        direction statistic (3 per lobe), the effective sample count (1 per lobe) and
        the batches so far (1). A render's
        samples add 9 floats per sample until the fit
        (renderers.integrators.control_variate_records)."""
        return {"model": LOBE_FLOATS * self.lobes, "fit": 4 * self.lobes + 1}


def vmf_config(**overrides: Any) -> VMFConfig:
    """The vMF preset with ``overrides`` (a method's ``vmf`` parameter)."""
    return VMFConfig(**overrides)


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` unit vectors on a spherical Fibonacci lattice (z uniform in (-1, 1),
    azimuth stepped by the golden angle): near-uniform coverage of the sphere."""
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    phi = index * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def kappa_from_mean_length(rbar: np.ndarray) -> np.ndarray:
    """Banerjee et al.'s approximation of the kappa whose mean length is ``rbar``, in 3-D."""
    rbar = np.clip(rbar, 0.0, 1.0 - 1e-6)
    return np.clip(rbar * (3.0 - rbar * rbar) / (1.0 - rbar * rbar), *KAPPA_RANGE)


class VMFModel:
    """The vMF mixtures of ``pixels`` pixels (module docstring); host arrays hold the
    fit, Dr.Jit arrays what the render reads.

    Its frames may be frozen (renderers.frozen): the arrays the render reads are
    uploaded after each fit at aligned addresses (``host_floats``), so a replay's key
    does not change with where NumPy allocated them."""

    freezable = True

    def __init__(self, config: VMFConfig, pixels: int) -> None:
        self.config = config
        self.pixels = pixels
        lobes = config.lobes
        self.mean = np.broadcast_to(fibonacci_directions(lobes), (pixels, lobes, 3)).copy()
        self.kappa = np.full((pixels, lobes), config.initial_kappa)
        self.amplitude = np.zeros((pixels, lobes, CHANNELS))
        self.direction_sum = np.zeros((pixels, lobes, 3))
        self.effective_samples = np.zeros((pixels, lobes))
        self.batches = np.zeros(pixels)
        self.nonfinite = 0
        self._upload()

    # ---- What the render reads: per lobe (pixel-major) mu, kappa, log-normaliser, a ----
    def _upload(self) -> None:
        from renderers.frozen import host_floats

        kappa = self.kappa
        # log(kappa / (2 pi (1 - exp(-2 kappa)))), -> log(1 / (4 pi)) as kappa -> 0.
        log_norm = np.log(kappa) - np.log(2 * np.pi) - np.log(-np.expm1(-2 * kappa))
        self.lobe_data = {name: host_floats(values)
                          for name, values in (("mean", self.mean), ("kappa", kappa),
                                               ("log_norm", log_norm),
                                               ("amplitude", self.amplitude))}

    def state(self) -> dict[str, Any]:
        """The Dr.Jit data a render reads (a frozen render's argument, renderers.frozen)."""
        return dict(self.lobe_data)

    def bind(self, state: dict[str, Any]) -> None:
        """Read :meth:`state`'s data from ``state``."""
        self.lobe_data = dict(state)

    def _lobes(self, pixel: Any, w: Any, active: Any) -> list[tuple[Any, list[Any]]]:
        """(v_k(w), [a_kc]) of every lobe k of ``pixel``."""
        import drjit as dr
        import mitsuba as mi

        data = self.lobe_data
        lobes = []
        for k in range(self.config.lobes):
            lobe = pixel * self.config.lobes + k
            mean = mi.Vector3f(*(dr.gather(mi.Float, data["mean"], lobe * 3 + i, active)
                                 for i in range(3)))
            kappa = dr.gather(mi.Float, data["kappa"], lobe, active)
            log_norm = dr.gather(mi.Float, data["log_norm"], lobe, active)
            density = dr.exp(log_norm + kappa * (dr.dot(mean, w) - 1.0))
            amplitude = [dr.gather(mi.Float, data["amplitude"], lobe * CHANNELS + c, active)
                         for c in range(CHANNELS)]
            lobes.append((density, amplitude))
        return lobes

    def eval(self, pixel: Any, w: Any, active: Any) -> Any:
        """g_p(w) = sum_k a_k v_k(w), per channel."""
        import mitsuba as mi

        value = [mi.Float(0.0) for _ in range(CHANNELS)]
        for density, amplitude in self._lobes(pixel, w, active):
            for c in range(CHANNELS):
                value[c] += amplitude[c] * density
        return mi.Spectrum(*value)

    def integral(self, pixel: Any, active: Any) -> Any:
        """G_p = sum_k a_k (each lobe integrates to 1 over the sphere), per channel."""
        import drjit as dr
        import mitsuba as mi

        total = [mi.Float(0.0) for _ in range(CHANNELS)]
        for k in range(self.config.lobes):
            lobe = pixel * self.config.lobes + k
            for c in range(CHANNELS):
                total[c] += dr.gather(mi.Float, self.lobe_data["amplitude"],
                                      lobe * CHANNELS + c, active)
        return mi.Spectrum(*total)

    def _batch(self, records: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The E-step over one render's samples under the current lobes: per pixel the
        batch's samples N, the sums N A_kc and N S_k and the lobes' effective sample
        counts (module docstring)."""
        import drjit as dr

        lobes = self._lobes(records.pixel, records.w, True)
        # pi_k proportional to the amplitudes' channel mean (uniform while they are all 0).
        priors = [sum(amplitude) / CHANNELS for _, amplitude in lobes]
        uniform = sum(priors) <= 0
        scores = [dr.select(uniform, 1.0, prior) * density
                  for prior, (density, _) in zip(priors, lobes, strict=True)]
        total_score = sum(scores)
        shape_weight = sum(records.weighted[c] for c in range(CHANNELS)) / CHANNELS
        amplitude_sums, direction_sums, shape_sums, square_sums = [], [], [], []
        for score in scores:
            gamma = dr.select(total_score > 0, score / total_score, 1.0 / len(scores))
            amplitude_sums.append([records.per_pixel_sum(records.weighted[c] * gamma)
                                   for c in range(CHANNELS)])
            direction_sums.append([records.per_pixel_sum(shape_weight * gamma * records.w[i])
                                   for i in range(3)])
            shape_sums.append(records.per_pixel_sum(shape_weight * gamma))
            square_sums.append(records.per_pixel_sum(dr.square(shape_weight * gamma)))
        count = records.per_pixel_sum(records.counts)
        dr.eval(amplitude_sums, direction_sums, shape_sums, square_sums, count)

        def host(sums: list[list[Any]]) -> np.ndarray:   # (pixels, lobes, 3)
            return np.stack([np.stack([np.asarray(v, dtype=np.float64) for v in lobe], -1)
                             for lobe in sums], axis=1)

        shape_sum, square_sum = (np.stack([np.asarray(v, dtype=np.float64) for v in sums], -1)
                                 for sums in (shape_sums, square_sums))
        # Kish's effective sample count of each lobe's weighted samples (0 if none weighs).
        effective = np.divide(shape_sum ** 2, square_sum, out=np.zeros_like(shape_sum),
                              where=square_sum > 0)
        return (np.asarray(count, dtype=np.float64), host(amplitude_sums),
                host(direction_sums), effective)

    def fit(self, records: Any) -> None:
        """The E-step over one render's samples, then for every pixel that had one the
        stepwise blend and the M-step."""
        self.nonfinite += records.nonfinite_count()
        count, amplitude_sums, direction_sums, effective = self._batch(records)
        fed = count > 0
        if not fed.any():
            return
        n = count[fed][:, None, None]
        eta = ((self.batches[fed] + 1.0) ** -self.config.step_exponent)[:, None, None]
        self.amplitude[fed] += eta * (amplitude_sums[fed] / n - self.amplitude[fed])
        self.direction_sum[fed] += eta * (direction_sums[fed] / n - self.direction_sum[fed])
        self.effective_samples[fed] += effective[fed]
        self.batches[fed] += 1
        self._m_step(fed)
        self._upload()

    def _m_step(self, fed: np.ndarray) -> None:
        """mu and kappa of the fed pixels' lobes from the running statistics, rbar
        shrunk by the prior (module docstring); a lobe with no weight (or no mean
        direction) keeps its mu and kappa."""
        weight = self.amplitude[fed].mean(axis=-1)
        length = np.linalg.norm(self.direction_sum[fed], axis=-1)
        moved = (weight > 0) & (length > 0)
        mean, kappa = self.mean[fed], self.kappa[fed]
        mean[moved] = self.direction_sum[fed][moved] / length[moved][:, None]
        samples = self.effective_samples[fed][moved]
        shrink = samples / (samples + self.config.prior_samples)
        kappa[moved] = kappa_from_mean_length(length[moved] / weight[moved] * shrink)
        self.mean[fed], self.kappa[fed] = mean, kappa

    def stats(self) -> dict[str, Any]:
        """What a run stores of the model: its config, floats per pixel, the EM batches
        each pixel has had on average and the non-finite samples left out."""
        return {"config": self.config.model_dump(mode="json"),
                "floats_per_pixel": self.config.floats_per_pixel(),
                "em_batches_per_pixel": float(self.batches.mean()),
                "nonfinite_samples": self.nonfinite}
