"""Property tests of every registered metric over extreme inputs (docs/stress.md).

Every metric of metrics.registry.METRICS is computed the way the executor computes
it (per seed with ``image_metrics`` and ``per_seed_values``, then ``aggregate``,
which reduces by each entry's aggregate form), on images of zeros, of 1e30, with
NaN and infinite pixels in the render or the reference, and with mismatched shapes.
The property: every stored value is a finite number or None (never a NaN average,
never an infinity JSON cannot hold), and mismatched shapes are a MetricError that
names both shapes.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jobs.protocol.executor import aggregate
from metrics.checks import MetricError
from metrics.errors import bias_variance, image_metrics, mrse, mse, per_cache_bias_variance
from metrics.flip import hdr_exposures
from metrics.registry import METRICS, per_seed_values
from metrics.statistics import RunningMoments, agreement_test, z_test

SHAPE = (8, 8, 3)
K = 3
EPS = 0.01
#: 1e30 as a float32 (hypothesis wants the exact value).
BIG = float(np.float32(1e30))


def every_metric(images: list[np.ndarray], ref: np.ndarray,
                 ref_variance: np.ndarray) -> tuple[dict, list[dict]]:
    """(aggregated, per seed) values of every registered metric, as the executor stores
    them; each render doubles as two 'frames' of its cache for the per-cache values."""
    with np.errstate(all="ignore"):
        exposures = hdr_exposures(np.nan_to_num(ref, nan=0.0, posinf=0.0, neginf=0.0))
    per_seed, moments = [], []
    for image in images:
        values = image_metrics(image, ref, eps=EPS, flip_exposures=exposures,
                               ref_variance=ref_variance)
        values.update(per_seed_values(image, ref))
        per_seed.append(values)
        frames = RunningMoments()
        frames.add(image)
        frames.add(image * np.float32(0.5))
        moments.append(frames)
    reference = SimpleNamespace(mean=ref, variance=ref_variance)
    return aggregate(per_seed, images, reference, EPS, 0.25, moments), per_seed


def assert_no_nonfinite(values: dict) -> None:
    """Every registered metric's stored values are finite numbers or None."""
    for metric in METRICS:
        for key in (metric.key, metric.seed_key, metric.ci_key):
            if key is None or key not in values:
                continue
            value = values[key]
            for number in (value if isinstance(value, list | tuple) else [value]):
                assert number is None or math.isfinite(number), (metric.name, key, value)


def check(images: list[np.ndarray], ref: np.ndarray, ref_variance: np.ndarray) -> dict:
    aggregated, per_seed = every_metric(images, ref, ref_variance)
    assert_no_nonfinite(aggregated)
    for values in per_seed:
        assert_no_nonfinite(values)
    return aggregated


def _images(value: float, ref_value: float) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    ref = np.full(SHAPE, ref_value, dtype=np.float32)
    images = [(np.full(SHAPE, value) * rng.uniform(0.5, 1.5, SHAPE)).astype(np.float32)
              for _ in range(K)]
    return images, ref, np.full(SHAPE, 1e-4 * ref_value**2, dtype=np.float32)


@pytest.mark.parametrize("value, ref_value", [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0),
                                              (1e30, 1e30), (1e30, 1.0), (1e-30, 1e-30)])
def test_extreme_constant_images_give_finite_values_or_none(value, ref_value):
    check(*_images(value, ref_value))


def test_identical_zero_images_have_zero_error():
    images, ref, variance = _images(0.0, 0.0)
    images = [np.zeros(SHAPE, np.float32)] * K
    values = check(images, ref, variance)
    assert values["mse_mean"] == 0.0 and values["mrse_mean"] == 0.0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", ["render", "reference", "variance"])
def test_a_nonfinite_pixel_is_left_out_and_counted(bad, where):
    images, ref, variance = _images(1.0, 1.0)
    target = {"render": images[0], "reference": ref, "variance": variance}[where]
    target[2, 3, 1] = bad
    if where == "variance" and bad < 0:      # a negative variance is an error, said so
        with pytest.raises(MetricError, match="negative"):
            every_metric(images, ref, variance)
        return
    _, per_seed = every_metric(images, ref, variance)
    values = check(images, ref, variance)
    # The pixel is counted where the render or the reference holds it ...
    counted = per_seed[0]["nonfinite_pixels"] if where == "render" \
        else per_seed[0]["ref_nonfinite_pixels"]
    assert counted == 1
    # ... and the other 63 pixels still give a number.
    assert values["mrse_mean"] is not None and math.isfinite(values["mrse_mean"])


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_render_without_any_finite_pixel_gives_none_not_nan(bad):
    images, ref, variance = _images(1.0, 1.0)
    images = [np.full(SHAPE, bad, np.float32)] * K
    values = check(images, ref, variance)
    assert values["mse_mean"] is None and values["mrse_mean"] is None


_pixels = hnp.arrays(np.float32, SHAPE, elements=st.one_of(
    st.floats(0.0, BIG, width=32), st.sampled_from([0.0, BIG, np.nan, np.inf, -np.inf])))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images=st.lists(_pixels, min_size=2, max_size=3), ref=_pixels,
       variance=hnp.arrays(np.float32, SHAPE, elements=st.floats(0.0, BIG, width=32)))
def test_any_mix_of_extreme_pixels_gives_finite_values_or_none(images, ref, variance):
    check(images, ref, variance)


@pytest.mark.parametrize("function", [
    lambda a, b: mse(a, b), lambda a, b: mrse(a, b), lambda a, b: image_metrics(a, b),
    lambda a, b: bias_variance([a, a], b), lambda a, b: per_seed_values(a, b),
    lambda a, b: z_test(a, a, b, b), lambda a, b: agreement_test(a, a, b, b),
    lambda a, b: per_cache_bias_variance([RunningMoments.merged(_moments(a), _moments(a))
                                          .estimate()], b),
], ids=["mse", "mrse", "image_metrics", "bias_variance", "per_seed", "z_test", "agreement",
        "per_cache"])
def test_mismatched_shapes_are_a_clear_error(function):
    test, ref = np.ones((8, 8, 3), np.float32), np.ones((8, 6, 3), np.float32)
    with pytest.raises(MetricError, match=r"8, 8|8, 6"):
        function(test, ref)


def _moments(image: np.ndarray) -> RunningMoments:
    moments = RunningMoments()
    moments.add(image)
    return moments


def test_a_nan_fed_to_the_agreement_test_fails_it_and_is_counted():
    """A NaN pixel never passes as agreement: it fails its pixel and is reported."""
    mean = np.ones((8, 8, 3))
    test = mean.copy()
    test[1, 1, 0] = np.nan
    result = agreement_test(test, np.full_like(mean, 0.01), mean, np.full_like(mean, 0.01))
    assert not result.passed and result.per_pixel.n_nonfinite == 1
