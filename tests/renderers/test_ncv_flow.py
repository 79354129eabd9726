"""The normalizing flow of the neural control variates (renderers/caches/flow.py):
forward then inverse is the identity, the density integrates to 1 over the sphere, and
the log-determinant is the finite-difference Jacobian's; each test rejects a planted
defect of the transform (a quadratic root without its 1/2, bin widths normalised
without the last bin, the density read at a bin's left vertex).

Randomly initialised networks give a nearly uniform flow (its log-density varies by
~0.3 %), which would hide the defects: the output layers are scaled up so that the
density varies by orders of magnitude. The networks are small (the transform, not the
MLP, is under test); the bins, repetitions and one-blob bins are the paper's.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from renderers.caches import flow as F

pytestmark = pytest.mark.usefixtures("mi")

CONDITION = 3


def random_flow(channels: int = 1, sharpen: float = 40.0, mix: float = 1e-3) -> F.SphereFlow:
    """A small random flow with the paper's bins, repetitions and one-blob bins, its
    output layers scaled by ``sharpen`` (module docstring), ``mix`` its uniform share."""
    config = F.FlowConfig(width=16, hidden_layers=2, channels=channels, uniform_mix=mix)
    flow = F.SphereFlow(config, CONDITION, seed=7)
    for nets in flow.networks:
        for net in nets:
            last = net.layers[-1]
            last.weights = last.weights * sharpen
            last.bias = last.bias * sharpen
    return flow


def random_rows(rng: np.random.Generator, count: int, n: int) -> list[mi.Float]:
    return [mi.Float(rng.random(n)) for _ in range(count)]


def round_trip_errors(flow: F.SphereFlow, n: int = 4096) -> tuple[float, float]:
    """max |inverse(forward(u)) - u| and max |log det forward + log det inverse|."""
    rng = np.random.default_rng(1)
    u = tuple(random_rows(rng, 2, n))
    condition = random_rows(rng, CONDITION, n)
    z, log_det = flow.forward(u, condition, 0)
    back, log_det_back = flow.inverse(z, condition, 0)
    position = max(float(np.max(np.abs(np.asarray(b) - np.asarray(a))))
                   for a, b in zip(u, back, strict=True))
    return position, float(np.max(np.abs(np.asarray(log_det) + np.asarray(log_det_back))))


def test_forward_then_inverse_is_the_identity(monkeypatch: pytest.MonkeyPatch) -> None:
    position, log_det = round_trip_errors(random_flow())
    assert position < 2e-4 and log_det < 2e-3, (position, log_det)

    # Planted: the quadratic's leading coefficient without its 1/2.
    def wrong_fraction(mass, width, left, right):
        linear = width * left
        root = dr.sqrt(dr.maximum(linear * linear + 4.0 * width * (right - left) * mass, 0))
        return dr.clip(2.0 * mass / dr.maximum(linear + root, 1e-30), 0.0, 1.0)

    monkeypatch.setattr(F, "bin_fraction", wrong_fraction)
    position, log_det = round_trip_errors(random_flow())
    assert position > 1e-2, position


def sphere_integrals(flow: F.SphereFlow, conditions: int = 2,
                     per_axis: int = 96) -> tuple[np.ndarray, float]:
    """int_S2 q_c(w | condition) dw per channel and condition, the midpoint rule on an
    equal-area grid of the sphere (cells of equal solid angle in (cos theta, phi)), and
    the ratio of the largest density to the smallest."""
    rng = np.random.default_rng(2)
    centres = (np.arange(per_axis) + 0.5) / per_axis
    cos_cells, phi_cells = (a.ravel() for a in np.meshgrid(centres, centres, indexing="ij"))
    cells = cos_cells.size
    cos_theta = mi.Float(np.tile(2.0 * cos_cells - 1.0, conditions))
    phi = mi.Float(np.tile(2.0 * math.pi * phi_cells, conditions))
    sin_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta)
    w = mi.Vector3f(sin_theta * dr.cos(phi), sin_theta * dr.sin(phi), cos_theta)
    values = rng.random((conditions, CONDITION))
    condition = [mi.Float(np.repeat(values[:, i], cells)) for i in range(CONDITION)]
    density = np.array([np.asarray(q) for q in flow.sphere_density(w, condition)])
    integrals = 4.0 * math.pi * density.reshape(-1, conditions, cells).mean(axis=2)
    return integrals, float(density.max() / density.min())


def test_density_integrates_to_one_on_the_sphere(monkeypatch: pytest.MonkeyPatch) -> None:
    flow = random_flow(channels=3)
    integrals, contrast = sphere_integrals(flow)
    assert np.all(np.abs(integrals - 1.0) < 5e-3), integrals
    assert contrast > 100.0, contrast   # far from uniform, or the test would show little

    # Planted: the widths' softmax normalised without the last bin, sum_{k<K} exp(W^_k)
    # (the heights normalised with those widths): the density spills past u = 1.
    right_widths = F.bin_widths

    def spilling_widths(raw, bins, mix):
        widths = right_widths(raw, bins, mix)
        lanes = dr.width(widths) // bins
        last = dr.gather(mi.Float, widths, dr.arange(mi.UInt32, lanes) * bins + bins - 1)
        return widths / dr.repeat(1.0 - last, bins)

    monkeypatch.setattr(F, "bin_widths", spilling_widths)
    integrals, _ = sphere_integrals(flow, conditions=1)
    assert np.all(np.abs(integrals - 1.0) > 2e-2), integrals


def test_a_large_uniform_share_keeps_the_density_normalised_and_floored(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """With a uniform share delta = 0.2 (the floor under the bins, 1e-3 by default, too
    small for the quadrature to see it) the density still integrates to 1 and is at
    least delta^4 / (4 pi) (4 layers of C' >= delta); planted: the floor added without
    scaling the learned part by 1 - delta (integral 1 + delta per layer)."""
    mix = 0.2
    integrals, _ = sphere_integrals(random_flow(mix=mix), conditions=1)
    assert np.all(np.abs(integrals - 1.0) < 5e-3), integrals
    w = mi.Vector3f(*(mi.Float(np.random.default_rng(4).normal(size=4096)) for _ in range(3)))
    condition = random_rows(np.random.default_rng(5), CONDITION, 4096)
    [density] = random_flow(mix=mix).sphere_density(w, condition)
    assert np.min(np.asarray(density)) >= mix**4 / (4.0 * math.pi) * (1.0 - 1e-5)

    monkeypatch.setattr(F, "with_uniform", lambda value, mix, uniform: value + mix * uniform)
    integrals, _ = sphere_integrals(random_flow(mix=mix), conditions=1)
    assert np.all(np.abs(integrals - 1.0) > 2e-2), integrals


def jacobian_errors(flow: F.SphereFlow, n: int = 2048, step: float = 1e-3) -> np.ndarray:
    """|det dz/du - exp(log det)| / exp(log det) with dz/du by central differences, at
    points a step inside the square."""
    rng = np.random.default_rng(3)
    u = [step + (1.0 - 2.0 * step) * rng.random(n) for _ in range(2)]
    condition = random_rows(rng, CONDITION, n)

    def latent(offset: tuple[float, float]) -> np.ndarray:
        z, _ = flow.forward((mi.Float(u[0] + offset[0]), mi.Float(u[1] + offset[1])),
                            condition, 0)
        return np.stack([np.asarray(z[0], dtype=np.float64), np.asarray(z[1], np.float64)])

    d0 = (latent((step, 0.0)) - latent((-step, 0.0))) / (2.0 * step)
    d1 = (latent((0.0, step)) - latent((0.0, -step))) / (2.0 * step)
    finite_differences = np.abs(d0[0] * d1[1] - d0[1] * d1[0])
    _, log_det = flow.forward((mi.Float(u[0]), mi.Float(u[1])), condition, 0)
    analytic = np.exp(np.asarray(log_det, dtype=np.float64))
    return np.abs(finite_differences - analytic) / analytic


def test_log_det_matches_finite_differences(monkeypatch: pytest.MonkeyPatch) -> None:
    # Milder than elsewhere: central differences straddling the kinks of a sharper
    # density's bins miss by more than the float32 tolerance.
    flow = random_flow(sharpen=12.0)
    errors = jacobian_errors(flow)
    assert np.median(errors) < 2e-3 and np.quantile(errors, 0.99) < 3e-2, \
        (np.median(errors), np.quantile(errors, 0.99))

    # Planted: the density read at the bin's left vertex instead of interpolated.
    monkeypatch.setattr(F, "bin_density", lambda fraction, left, right: left)
    errors = jacobian_errors(flow)
    assert np.median(errors) > 1e-2, np.median(errors)
