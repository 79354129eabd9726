"""Statistical tools for Monte Carlo tests and converged references.

- :class:`RunningMoments`: per-pixel running mean and variance of a stream of
  images (Welford), e.g. the frames of one seed for per-cache rBias^2 / rVar.
- :class:`PassAccumulator`: the checked variant for independent render passes
  (two Welford halves merged with Chan et al.'s pairwise formula), with the
  even/odd split halves that measure a reference's own residual error.
- :func:`z_test`: the per-pixel two-sample z-test of Mitsuba 3's render tests
  (``src/render/tests/test_renders.py``), with a Šidák correction over all
  tested pixel-channels.
- :func:`aggregate_test`: chi-square and signed-mean statistics over pixel
  blocks, which catch a bias of a few percent that no single pixel shows;
  :func:`agreement_test` runs both tests.
- :func:`image_mean_test`: the seeds' image mean against the reference's, for
  renders whose pixels share samples (spatial reuse), where the block test's
  independent-pixel variances are too small.
- :func:`mean_confidence_interval`: Student-t interval of a mean over seeds.
- :func:`welch_test`: Welch's two-sample t-test of two sets of values (seeds, commits),
  the one the run comparison, the CI gate and the metric history use;
  :func:`welch_interval` its interval of the difference of the means.
- :func:`positive_mean_interval`: the interval of the mean of a non-negative quantity
  (an error such as MRSE), on the log scale so that it never goes below zero;
  :func:`interval_or_reason` says why there is none; :func:`log_scale_interval` the
  same from an estimate and its standard error, :func:`chi2_variance_interval` that of
  a Gaussian sample variance.

Distributions (Student t, chi-square, normal tails) come from ``scipy.stats``
and ``scipy.special``; SciPy is a declared dependency of the project. They are
imported where they are used: importing ``scipy.stats`` takes ~1.2 s, which every
command of the CLI paid at start (``nirc-bench --help``: 3.8 s) through this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from metrics.checks import MetricError

# ---------------------------------------------------------------------------
# Confidence intervals over a few seeds
# ---------------------------------------------------------------------------


@lru_cache(maxsize=1024)
def t_quantile(probability: float, dof: float) -> float:
    """The ``probability`` quantile of Student's t with ``dof`` degrees of freedom
    (``scipy.stats.t.ppf``), remembered: intervals ask for a handful of (level, dof)
    pairs again and again (the CI gate's calibration some 10^4 times), and each SciPy
    call costs ~0.4 ms of argument handling."""
    from scipy import stats
    return float(stats.t.ppf(probability, dof))


def mean_confidence_interval(values: np.ndarray | list[float],
                             level: float = 0.95) -> tuple[float, float, float]:
    """(mean, lo, hi): the Student-t confidence interval of the mean of ``values``.

    ``values`` are independent samples (e.g. one MRSE per seed); the interval
    is mean +- t_{(1+level)/2, n-1} * s / sqrt(n) with the sample standard
    deviation s. Needs n >= 2 finite values.
    """
    arr = np.asarray(values, dtype=np.float64).ravel()
    if arr.size < 2:
        raise MetricError(f"a confidence interval needs at least 2 values, got {arr.size}")
    if not np.isfinite(arr).all():
        raise MetricError("cannot build a confidence interval from non-finite values")
    if not 0.0 < level < 1.0:
        raise MetricError(f"confidence level must be in (0, 1), got {level}")
    mean = float(arr.mean())
    half_width = (t_quantile(0.5 * (1.0 + level), arr.size - 1)
                  * float(arr.std(ddof=1)) / math.sqrt(arr.size))
    return mean, mean - half_width, mean + half_width


#: Fewer values than this give no interval of a mean: with 2 seeds the Student t has one
#: degree of freedom (critical value 12.7), and the interval spans most of the axis.
MIN_INTERVAL_VALUES = 3

#: How :func:`positive_mean_interval` is made, as tables and the API state it.
POSITIVE_INTERVAL_NOTE = ("95 % interval of the mean on the log scale (delta method, "
                          "Student t with K-1 degrees of freedom)")


def positive_mean_interval(values: np.ndarray | list[float],
                           level: float = 0.95) -> tuple[float, float]:
    """(lo, hi): a ``level`` confidence interval of the mean of non-negative ``values``
    that stays above zero.

    The interval is built for log(mean) by the delta method, whose standard error is
    the coefficient of variation s / (mean sqrt(n)), with the Student-t critical
    value on n - 1 degrees of freedom, and mapped back:
    mean x exp(-+ t s / (mean sqrt(n))). Errors over seeds are right-skewed and
    bounded by zero, which the symmetric interval mean +- t s / sqrt(n) ignores (with
    few seeds its lower end goes negative). Needs at least
    :data:`MIN_INTERVAL_VALUES` finite, non-negative values; all zero gives (0, 0).
    """
    arr = np.asarray(values, dtype=np.float64).ravel()
    if arr.size < MIN_INTERVAL_VALUES:
        raise MetricError(f"an interval needs at least {MIN_INTERVAL_VALUES} values, got "
                          f"{arr.size}")
    if not np.isfinite(arr).all() or (arr < 0).any():
        raise MetricError("the interval of a non-negative mean needs finite values >= 0")
    if not 0.0 < level < 1.0:
        raise MetricError(f"confidence level must be in (0, 1), got {level}")
    mean = float(arr.mean())
    if mean == 0.0:
        return 0.0, 0.0
    return log_scale_interval(mean, float(arr.std(ddof=1)) / math.sqrt(arr.size),
                              arr.size - 1, level)


def log_scale_interval(estimate: float, standard_error: float, dof: float,
                       level: float = 0.95) -> tuple[float, float]:
    """(lo, hi) = estimate x exp(-+ t se / estimate): the Student-t interval (``dof``
    degrees of freedom) of log(estimate) by the delta method, mapped back, for a positive
    quantity whose estimate has standard error ``standard_error``."""
    if not estimate > 0:
        raise MetricError(f"a log-scale interval needs an estimate > 0, got {estimate}")
    half_width = t_quantile(0.5 * (1.0 + level), dof) * standard_error / estimate
    return estimate * math.exp(-half_width), estimate * math.exp(half_width)


def chi2_variance_interval(variance: float, dof: int,
                           level: float = 0.95) -> tuple[float, float]:
    """(lo, hi) of a variance whose estimate is variance x chi2_dof / dof (a Gaussian
    sample variance on ``dof`` degrees of freedom): dof v / chi2_{(1+level)/2, dof} to
    dof v / chi2_{(1-level)/2, dof}."""
    from scipy import stats
    if dof < 1 or not variance >= 0:
        raise MetricError(f"a chi-square interval needs dof >= 1 and a variance >= 0, got "
                          f"{dof} and {variance}")
    upper_q, lower_q = stats.chi2.ppf([0.5 * (1.0 + level), 0.5 * (1.0 - level)], dof)
    return dof * variance / float(upper_q), dof * variance / float(lower_q)


def interval_or_reason(values: list[float | None]) -> tuple[tuple[float, float] | None, str]:
    """The 95 % :func:`positive_mean_interval` of the finite ``values`` with how it was
    made, or None with why there is none (too few seeds)."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    if len(finite) < MIN_INTERVAL_VALUES:
        return None, (f"no interval: {len(finite)} seed{'s' if len(finite) != 1 else ''} "
                      f"(an interval needs {MIN_INTERVAL_VALUES} or more)")
    return positive_mean_interval(finite), POSITIVE_INTERVAL_NOTE


# ---------------------------------------------------------------------------
# Progressive per-pixel mean and variance over independent passes
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class MeanEstimate:
    """A per-pixel Monte Carlo mean with the variance *of that mean*."""

    mean: np.ndarray              # per-pixel mean of the passes
    variance_of_mean: np.ndarray  # unbiased pass variance / count
    count: int                    # passes averaged


class RunningMoments:
    """Welford running mean and sum of squared deviations of a stream of images (float64).

    Unlike :class:`PassAccumulator` it checks nothing: a non-finite value
    propagates into that pixel's mean and variance, so a caller that must not
    fail on a NaN frame (the executor's per-seed frame statistics) can count
    and exclude such pixels afterwards.
    """

    __slots__ = ("count", "mean", "m2")

    def __init__(self) -> None:
        self.count = 0                      # images seen
        self.mean: np.ndarray | None = None  # running per-pixel mean
        self.m2: np.ndarray | None = None    # running sum of squared deviations

    def add(self, image: np.ndarray) -> None:
        x = np.asarray(image, dtype=np.float64)
        if self.mean is None or self.m2 is None:
            self.count, self.mean, self.m2 = 1, x.copy(), np.zeros_like(x)
            return
        self.count += 1
        delta = x - self.mean
        self.mean += delta / self.count
        # Welford: (x - old mean) * (x - new mean) keeps m2 exact without
        # subtracting two large sums of squares.
        self.m2 += delta * (x - self.mean)

    def estimate(self) -> MeanEstimate:
        """The mean with the variance of the mean, unbiased sample variance / count."""
        if self.count < 2 or self.mean is None or self.m2 is None:
            raise MetricError(f"a variance needs at least 2 images, have {self.count}")
        return MeanEstimate(self.mean.copy(), self.m2 / (self.count - 1) / self.count,
                            self.count)

    @staticmethod
    def merged(a: RunningMoments, b: RunningMoments) -> RunningMoments:
        """Moments of the union of two disjoint streams (Chan, Golub & LeVeque)."""
        if b.count == 0:
            return a
        if a.count == 0:
            return b
        assert a.mean is not None and a.m2 is not None and b.mean is not None and b.m2 is not None
        out = RunningMoments()
        out.count = a.count + b.count
        delta = b.mean - a.mean
        out.mean = a.mean + delta * (b.count / out.count)
        out.m2 = a.m2 + b.m2 + delta * delta * (a.count * b.count / out.count)
        return out


class PassAccumulator:
    """Progressive per-pixel mean and variance over independent, identically distributed passes.

    Each ``add`` takes one pass image (e.g. the mean of 64 spp rendered with its
    own seed). Passes alternate between two half accumulators (even passes to
    half A, odd to half B), each updated with Welford's algorithm in float64;
    the full statistics are the Chan et al. merge of the halves, so the halves
    cost no extra memory and are always available for a reference-vs-reference
    check (:meth:`split_halves`).

    Passes must have equal sample counts: the variance is that of pass values.
    A pass with a non-finite pixel is rejected with MetricError rather than
    averaged, since one NaN would poison every later mean.
    """

    def __init__(self) -> None:
        self._halves = (RunningMoments(), RunningMoments())  # even passes, odd passes
        self._total: RunningMoments | None = None      # merged halves, cached until the next add

    def add(self, pass_image: np.ndarray) -> None:
        x = np.asarray(pass_image, dtype=np.float64)
        first = self._halves[0].mean
        if first is not None and x.shape != first.shape:
            raise MetricError(f"pass image shape {x.shape} does not match the "
                              f"accumulated shape {first.shape}")
        bad = int(np.count_nonzero(~np.isfinite(x)))
        if bad:
            raise MetricError(f"pass {self.count} has {bad} non-finite values; "
                              "refusing to average them into the accumulator")
        self._halves[self.count % 2].add(x)
        self._total = None

    @property
    def count(self) -> int:
        """Number of passes added."""
        return self._halves[0].count + self._halves[1].count

    def _merged(self) -> RunningMoments:
        if self._total is None:
            self._total = RunningMoments.merged(*self._halves)
        return self._total

    def _require(self, passes: int, what: str) -> None:
        if self.count < passes:
            raise MetricError(f"{what} needs at least {passes} passes, have {self.count}")

    @property
    def mean(self) -> np.ndarray:
        """Per-pixel mean of all passes (float64 copy)."""
        self._require(1, "the mean")
        return self._merged().mean.copy()

    @property
    def variance(self) -> np.ndarray:
        """Per-pixel unbiased sample variance of the pass values (float64)."""
        self._require(2, "the variance")
        total = self._merged()
        return total.m2 / (total.count - 1)

    @property
    def variance_of_mean(self) -> np.ndarray:
        """Per-pixel variance of :attr:`mean` itself: variance / count."""
        return self.variance / self.count

    def estimate(self) -> MeanEstimate:
        """The mean with its variance, ready for :func:`z_test`."""
        return MeanEstimate(self.mean, self.variance_of_mean, self.count)

    def relative_stderr(self, eps: float = 0.01) -> float:
        """Root-mean-square relative standard error of the mean, regularised like MRSE.

        sqrt(mean over pixels and channels of variance_of_mean / (mean^2 + eps)).
        Its square is the expected MRSE of this mean against the true image
        (with the mean standing in for the truth in the denominator), so a
        target of e.g. 0.01 means "this reference is ~1e-4 MRSE from converged".
        ``eps`` (as in MRSE) keeps near-black pixels from dominating.
        """
        mean = self._merged().mean
        return float(np.sqrt(np.mean(self.variance_of_mean / (mean * mean + eps))))

    def split_halves(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean of the even passes, mean of the odd passes): two independent half estimates."""
        self._require(2, "split halves")
        return self._halves[0].mean.copy(), self._halves[1].mean.copy()

    def half_estimates(self) -> tuple[MeanEstimate, MeanEstimate]:
        """Both halves with their own variance of the mean (each needs >= 2 passes)."""
        self._require(4, "split-half variances")
        return self._halves[0].estimate(), self._halves[1].estimate()


# ---------------------------------------------------------------------------
# Two-sample z-test with Šidák correction (as in Mitsuba 3's render tests)
# ---------------------------------------------------------------------------

def sidak_alpha(alpha: float, n_tests: int) -> float:
    """Per-test level so that n independent tests have family-wise level ``alpha``.

    1 - (1 - alpha)^(1/n), computed with log1p/expm1 because for n ~ 1e5 the
    direct form loses most digits to cancellation.
    """
    if not 0.0 < alpha < 1.0:
        raise MetricError(f"significance level must be in (0, 1), got {alpha}")
    if n_tests < 1:
        raise MetricError(f"need at least one test, got {n_tests}")
    return -math.expm1(math.log1p(-alpha) / n_tests)


@dataclass(frozen=True)
class ZTestResult:
    """Outcome of :func:`z_test` over all pixel-channels."""

    p_values: np.ndarray          # two-sided p-value per pixel-channel (0 where non-finite)
    alpha: float                  # family-wise significance level requested
    alpha_corrected: float        # Šidák per-pixel-channel level
    n_tested: int                 # pixel-channels tested
    n_failed: int                 # pixel-channels with p <= alpha_corrected
    n_nonfinite: int              # pixel-channels with a non-finite input (counted as failed)
    min_p_value: float
    worst_index: tuple[int, ...]  # index of the smallest p-value
    passed: bool                  # no pixel-channel rejected the null hypothesis

    def summary(self) -> str:
        verdict = "passed" if self.passed else "FAILED"
        text = (f"z-test {verdict}: {self.n_failed} of {self.n_tested} pixel-channels below "
                f"the Šidák level {self.alpha_corrected:.3g} (family-wise alpha {self.alpha:g}); "
                f"min p-value {self.min_p_value:.3g} at index {self.worst_index}")
        if self.n_nonfinite:
            text += f"; {self.n_nonfinite} pixel-channels had non-finite inputs"
        return text


def _two_sided_p_values(mean_a: np.ndarray, var_a: np.ndarray, mean_b: np.ndarray,
                        var_b: np.ndarray, dof: float | None = None) -> np.ndarray:
    """p = P(|Z| >= |z|) with z = (a - b) / sqrt(var_a + var_b), or P(|T_dof| >= |z|)
    for variances estimated with ``dof`` degrees of freedom; degenerate cases handled."""
    from scipy import special, stats
    diff = mean_a - mean_b
    var = var_a + var_b
    p = np.zeros(diff.shape, dtype=np.float64)
    positive = var > 0
    z = np.abs(diff[positive]) / np.sqrt(var[positive])
    # erfc(|z|/sqrt 2) keeps the tiny p-values that a Šidák level (~1e-7) needs;
    # 1 - cdf would round them to 0.
    p[positive] = (special.erfc(z / math.sqrt(2.0)) if dof is None
                   else 2.0 * stats.t.sf(z, dof))
    # Zero variance on both sides: the means are exact, so they agree or they don't.
    p[(var == 0) & (diff == 0)] = 1.0
    return p


def _paired_means(mean_a: np.ndarray, var_a: np.ndarray, mean_b: np.ndarray,
                  var_b: np.ndarray) -> tuple[np.ndarray, ...]:
    """Two means and the variances of the means, as float64 arrays of one shape."""
    if np.shape(mean_a) != np.shape(mean_b):
        raise MetricError(f"mean shapes differ: {np.shape(mean_a)} vs {np.shape(mean_b)}")
    try:
        a, va, b, vb = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                             for x in (mean_a, var_a, mean_b, var_b)))
    except ValueError:
        raise MetricError(f"variance shapes {np.shape(var_a)}, {np.shape(var_b)} do not "
                          f"broadcast to the mean shape {np.shape(mean_a)}") from None
    if np.any((va < 0) | (vb < 0)):
        raise MetricError("variances must be >= 0")
    return a, va, b, vb


def z_test(mean_a: np.ndarray, var_a: np.ndarray, mean_b: np.ndarray, var_b: np.ndarray,
           alpha: float = 0.01, dof: float | None = None) -> ZTestResult:
    """Per-pixel-channel two-sample z-test of "both means estimate the same image".

    ``var_a`` and ``var_b`` are variances *of the means* (the pass variance
    already divided by the pass count, e.g. :attr:`PassAccumulator.variance_of_mean`);
    they broadcast against the means. z = (a - b) / sqrt(var_a + var_b) and the
    two-sided p-value is erfc(|z| / sqrt 2).

    Mitsuba 3's ``test_renders.py`` tests a render against a reference this way
    (one-sided on the reference's variance, clamped at 1e-4) and corrects for
    the N simultaneous tests with Šidák: the per-test level is
    1 - (1 - alpha)^(1/N). We do the same over the N = ``n_tested``
    pixel-channels, and pass only if *no* pixel-channel falls at or below it
    (Mitsuba additionally tolerates 0.25 % failing pixels; with Šidák the
    family-wise false-failure rate is already ``alpha``, so we do not).

    Elements where both variances are 0 pass when the means are equal and fail
    otherwise; elements with a non-finite input fail (p = 0). The z statistic
    assumes the variance estimates are accurate: use many passes per side
    (hundreds), or the heavier tails of estimated variances cause false failures.
    With variances estimated from few passes give ``dof`` (e.g. passes - 1): z is
    then read as a Student t with ``dof`` degrees of freedom (Welch's test with the
    smaller side's degrees of freedom, conservative), whose tails are that heavy.
    """
    if dof is not None and not dof > 0:
        raise MetricError(f"degrees of freedom must be > 0, got {dof}")
    a, va, b, vb = _paired_means(mean_a, var_a, mean_b, var_b)
    finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(va) & np.isfinite(vb)
    n_tested = int(a.size)
    alpha_corrected = sidak_alpha(alpha, n_tested)

    p_values = np.zeros(a.shape, dtype=np.float64)
    p_values[finite] = _two_sided_p_values(a[finite], va[finite], b[finite], vb[finite], dof)
    n_failed = int(np.count_nonzero(p_values <= alpha_corrected))
    worst = np.unravel_index(int(np.argmin(p_values)), p_values.shape)
    return ZTestResult(
        p_values=p_values,
        alpha=float(alpha),
        alpha_corrected=alpha_corrected,
        n_tested=n_tested,
        n_failed=n_failed,
        n_nonfinite=int(np.count_nonzero(~finite)),
        min_p_value=float(p_values[worst]),
        worst_index=tuple(int(i) for i in worst),
        passed=n_failed == 0,
    )


def welch_test(a: np.ndarray | list[float], b: np.ndarray | list[float],
               alternative: str = "two-sided") -> Any:
    """Welch's t-test of mean(a) - mean(b): two samples with unequal variances, the
    t statistic over sqrt(s_a^2 / n_a + s_b^2 / n_b) read with the Welch-Satterthwaite
    degrees of freedom (Welch 1947), as SciPy's ``ttest_ind(equal_var=False)``.

    ``alternative``: ``"two-sided"``, ``"greater"`` (mean(a) > mean(b)) or ``"less"``.
    The result has ``statistic`` and ``pvalue``; :func:`welch_interval` gives the
    confidence interval of the difference. Two constant samples give an infinite
    statistic (different values) or NaN (equal ones); callers decide what that means
    for them.

    SciPy's test from the samples' means, deviations and sizes
    (``ttest_ind_from_stats``): the same statistic and p-value as ``ttest_ind`` on the
    samples at a tenth of the cost, which matters to the CI gate's calibration, which
    runs this test some 10^4 times (tests/jobs/test_ci.py).
    """
    from scipy import stats
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return stats.ttest_ind_from_stats(a.mean(), a.std(ddof=1), a.size,
                                      b.mean(), b.std(ddof=1), b.size,
                                      equal_var=False, alternative=alternative)


def welch_interval(a: np.ndarray | list[float], b: np.ndarray | list[float],
                   level: float = 0.95) -> tuple[float, float]:
    """The two-sided ``level`` confidence interval of mean(a) - mean(b) of
    :func:`welch_test` (SciPy's ``ttest_ind(equal_var=False).confidence_interval``)."""
    from scipy import stats
    result = stats.ttest_ind(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64),
                             equal_var=False)
    low, high = result.confidence_interval(level)
    return float(low), float(high)


# ---------------------------------------------------------------------------
# Aggregate test over pixel blocks (catches few-percent biases the per-pixel test misses)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class AggregateTestResult:
    """Outcome of :func:`aggregate_test`: two statistics per channel over tile means.

    The fields report the channel with the smallest p-value of each statistic.
    """

    n_blocks: int         # tiles tested per channel
    block_pixels: int     # pixels per tile side (tiles of block x block pixels)
    chi2: float           # sum over tiles of z_B^2 (worst channel), chi-square under the null
    p_chi2: float         # its upper-tail p-value
    mean_z: float         # image-wide mean difference / its standard error (worst channel)
    p_mean: float         # its two-sided p-value
    alpha: float          # family-wise level over all statistics and channels
    passed: bool          # every p-value above alpha / (2 C) (Bonferroni)

    def summary(self) -> str:
        verdict = "passed" if self.passed else "FAILED"
        return (f"aggregate test {verdict} over {self.n_blocks} tiles of "
                f"{self.block_pixels}x{self.block_pixels} px per channel: chi2 {self.chi2:.1f} "
                f"(p {self.p_chi2:.3g}), mean z {self.mean_z:+.2f} (p {self.p_mean:.3g}); "
                f"level {self.alpha:g}")


def _tile_sums(x: np.ndarray, block: int) -> np.ndarray:
    """Sums over block x block tiles of an (H, W, C) array (trailing rows/columns dropped)."""
    h, w = (x.shape[0] // block) * block, (x.shape[1] // block) * block
    if h == 0 or w == 0:
        raise MetricError(f"the image ({x.shape[0]}x{x.shape[1]}) is smaller than one "
                          f"{block}x{block} block")
    tiles = x[:h, :w].reshape(h // block, block, w // block, block, x.shape[2])
    return tiles.sum(axis=(1, 3))


def _channel_statistics(d: np.ndarray, v: np.ndarray, df: np.ndarray | None
                        ) -> tuple[int, float, float, float, float]:
    """(tiles, chi2, p_chi2, mean z, p_mean) of one channel's tile differences d and
    variances v (NaN d: a tile left out; inf: a tile that fails)."""
    from scipy import stats
    tested = ~np.isnan(d)
    n = int(np.count_nonzero(tested))
    if n == 0:
        return 0, 0.0, 1.0, 0.0, 1.0
    d, v = d[tested], v[tested]
    if not (np.isfinite(d).all() and np.isfinite(v).all()) or np.any((v == 0) & (d != 0)):
        return n, math.inf, 0.0, math.nan, 0.0
    positive = v > 0
    z = np.zeros_like(d)
    z[positive] = d[positive] / np.sqrt(v[positive])
    if df is not None:
        t = z[positive]
        z[positive] = np.sign(t) * stats.norm.isf(stats.t.sf(np.abs(t), df[tested][positive]))
    chi2 = float(np.sum(z * z))
    total_v = float(v.sum())
    mean_z = float(d.sum() / math.sqrt(total_v)) if total_v > 0 else 0.0
    return n, chi2, float(stats.chi2.sf(chi2, n)), mean_z, float(2.0 * stats.norm.sf(abs(mean_z)))


def aggregate_test(mean_a: np.ndarray, var_a: np.ndarray, mean_b: np.ndarray,
                   var_b: np.ndarray, *, dof: float | None = None, block: int = 4,
                   alpha: float = 0.01) -> AggregateTestResult:
    """Test "both images have the same expectation" on means over pixel tiles.

    The per-pixel Šidák test (:func:`z_test`) only rejects a pixel whose
    difference is ~5 standard deviations, so a bias of a few percent spread
    over the image passes it. Here each channel is cut into ``block`` x
    ``block`` tiles; per tile B the mean difference d_B and its variance
    v_B = sum (var_a + var_b) / n^2 give z_B = d_B / sqrt(v_B), and per channel

    - chi2 = sum_B z_B^2, chi-square with B degrees of freedom under the null:
      any pattern of bias raises it (``p_chi2``);
    - S = sum_B d_B / sqrt(sum_B v_B), the image-wide mean difference over its
      standard error, standard normal under the null: a bias of one sign over
      the image shifts it by its size in units of the image's standard error
      (``p_mean``). The variances are summed *before* dividing because
      per-tile variance estimates of heavy-tailed pixels (fireflies) are noisy
      and correlated with the tile means; a sum of per-tile z values then has
      a spread well above 1 and rejects correct renders (measured: 2 of 12
      pairs of unbiased cornell-box renders at alpha 0.01), the pooled ratio
      does not (0 of 12).

    The channels of a render share its paths, so they are not independent:
    each channel is tested on its own and the 2 C p-values are combined by
    Bonferroni (every one must exceed alpha / (2 C)), which holds under any
    dependence.

    ``var_a`` / ``var_b`` are variances of the means (as for :func:`z_test`).
    When the variances are estimated with ``dof`` degrees of freedom per pixel
    (e.g. passes - 1), each z_B is a Student t with the Welch-Satterthwaite
    degrees of freedom of its tile and is mapped to the standard normal with
    the same tail probability before squaring, so the chi-square holds for
    few passes too. Tiles where both variances are 0 are left out when their
    means agree and fail otherwise; non-finite inputs fail.
    """
    if not 0.0 < alpha < 1.0:
        raise MetricError(f"significance level must be in (0, 1), got {alpha}")
    if block < 1:
        raise MetricError(f"block size must be >= 1, got {block}")
    if dof is not None and not dof > 0:
        raise MetricError(f"degrees of freedom must be > 0, got {dof}")
    a, va, b, vb = _paired_means(mean_a, var_a, mean_b, var_b)
    if a.ndim == 2:
        a, va, b, vb = (x[..., None] for x in (a, va, b, vb))
    if a.ndim != 3:
        raise MetricError(f"images must be (H, W) or (H, W, C), got shape {a.shape}")
    n = block * block
    finite = _tile_sums((np.isfinite(a) & np.isfinite(b) & np.isfinite(va)
                         & np.isfinite(vb)).astype(np.float64), block) == n
    with np.errstate(invalid="ignore", over="ignore"):
        d = _tile_sums(a - b, block) / n
        v = _tile_sums(va + vb, block) / n**2
    d = np.where(finite, d, np.inf)
    d[finite & (v == 0) & (d == 0)] = np.nan     # exact agreement: nothing to test
    df = None
    if dof is not None:
        # Welch-Satterthwaite over the 2 n independent variance estimates of the
        # tile (one per pixel and side): df_B = (sum_i va_i + vb_i)^2 / sum_i
        # (va_i^2 + vb_i^2) / dof.
        with np.errstate(invalid="ignore", divide="ignore"):
            df = _tile_sums(va + vb, block) ** 2 / (_tile_sums(va * va + vb * vb, block) / dof)
    channels = [_channel_statistics(d[..., c], v[..., c], None if df is None else df[..., c])
                for c in range(d.shape[-1])]
    worst_chi2 = min(channels, key=lambda s: s[2])
    worst_mean = min(channels, key=lambda s: s[4])
    level = alpha / (2 * len(channels))
    passed = all(s[2] > level and s[4] > level for s in channels)
    return AggregateTestResult(max(s[0] for s in channels), block, worst_chi2[1],
                               worst_chi2[2], worst_mean[3], worst_mean[4], float(alpha),
                               passed)


@dataclass(frozen=True)
class ImageMeanTestResult:
    """Outcome of :func:`image_mean_test` (the worst channel's statistic)."""

    t: float              # (seeds' image mean - reference's) / its standard error
    dof: float            # Welch-Satterthwaite degrees of freedom of t
    p_value: float        # two-sided
    seeds: int
    alpha: float          # family-wise level over the channels
    passed: bool          # every channel's p-value above alpha / C (Bonferroni)

    def summary(self) -> str:
        verdict = "passed" if self.passed else "FAILED"
        return (f"image-mean test {verdict} over {self.seeds} seeds: t {self.t:+.2f} "
                f"({self.dof:.1f} dof, p {self.p_value:.3g}); level {self.alpha:g}")


def image_mean_test(seed_images: np.ndarray, ref_mean: np.ndarray, ref_var: np.ndarray,
                    alpha: float = 0.01) -> ImageMeanTestResult:
    """Test "the seeds' image mean has the reference's expectation" per channel, for
    renders whose pixels are correlated (spatial reuse shares samples between pixels),
    where :func:`aggregate_test`'s tile variances, summed as if pixels were
    independent, are too small.

    ``seed_images`` (K, H, W, C) are K independent renders; each one's mean over the
    pixels is one sample, whatever the correlation between its pixels, so their
    sample variance s^2 / K measures the error of their average. The reference's
    pixels are independent: its image mean has variance sum(ref_var) / N^2 (``ref_var``:
    variances of the reference's means). t = (mean - ref) / sqrt(s^2 / K + v_ref),
    Student t with Welch-Satterthwaite degrees of freedom (the reference's variance
    counted as known); channels combined by Bonferroni. Non-finite inputs fail.
    """
    from scipy import stats
    if not 0.0 < alpha < 1.0:
        raise MetricError(f"significance level must be in (0, 1), got {alpha}")
    images = np.asarray(seed_images, dtype=np.float64)
    if images.ndim != 4 or images.shape[0] < 2:
        raise MetricError(f"need (K >= 2, H, W, C) seed images, got shape {images.shape}")
    _, _, ref, ref_v = _paired_means(images[0], np.zeros(images.shape[1:]), ref_mean, ref_var)
    channels = images.shape[-1]
    if not (np.isfinite(images).all() and np.isfinite(ref).all() and np.isfinite(ref_v).all()):
        return ImageMeanTestResult(math.nan, math.nan, 0.0, images.shape[0], float(alpha),
                                   False)
    seeds = images.shape[0]
    means = images.reshape(seeds, -1, channels).mean(axis=1)          # (K, C)
    var_seeds = means.var(axis=0, ddof=1) / seeds
    pixels = ref.shape[0] * ref.shape[1]
    var_ref = ref_v.reshape(-1, channels).sum(axis=0) / pixels ** 2
    diff = means.mean(axis=0) - ref.reshape(-1, channels).mean(axis=0)
    total = var_seeds + var_ref
    results = []
    for c in range(channels):
        if total[c] == 0:
            results.append((0.0 if diff[c] == 0 else math.inf, math.inf,
                            1.0 if diff[c] == 0 else 0.0))
            continue
        t = float(diff[c] / math.sqrt(total[c]))
        dof = (float(total[c] ** 2 / (var_seeds[c] ** 2 / (seeds - 1)))
               if var_seeds[c] > 0 else math.inf)
        results.append((t, dof, float(2.0 * stats.t.sf(abs(t), dof))))
    worst = min(results, key=lambda r: r[2])
    passed = all(r[2] > alpha / channels for r in results)
    return ImageMeanTestResult(worst[0], worst[1], worst[2], seeds, float(alpha), passed)


@dataclass(frozen=True)
class AgreementResult:
    """Per-pixel Šidák z-test and an aggregate test of one image pair: the block test,
    or the image-mean test for correlated pixels."""

    per_pixel: ZTestResult
    aggregate: AggregateTestResult | ImageMeanTestResult

    @property
    def passed(self) -> bool:
        return self.per_pixel.passed and self.aggregate.passed

    def summary(self) -> str:
        return f"{self.per_pixel.summary()}; {self.aggregate.summary()}"


def agreement_test(mean_a: np.ndarray, var_a: np.ndarray, mean_b: np.ndarray,
                   var_b: np.ndarray, *, dof: float | None = None, block: int = 4,
                   alpha: float = 0.01) -> AgreementResult:
    """Both tests at level ``alpha`` each: a render agrees with a reference only if
    no pixel is an outlier (:func:`z_test`) and the block means agree
    (:func:`aggregate_test`). Statistical render tests use this. ``dof``: degrees of
    freedom of the variance estimates, for both tests."""
    return AgreementResult(z_test(mean_a, var_a, mean_b, var_b, alpha=alpha, dof=dof),
                           aggregate_test(mean_a, var_a, mean_b, var_b, dof=dof, block=block,
                                          alpha=alpha))
