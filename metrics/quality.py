"""The quality verdict of a run: degenerate input is told, not scored.

A run's numbers only mean something when its inputs do: a scene without an
emitter scores MRSE 0, a black reference makes every relative error divide by
eps alone, negative radiance breaks FLIP's tone mapping, and NaN pixels cannot
be averaged. :func:`assess` turns plain facts about a run (pixel counts,
reference statistics, emitter count, cache training steps; see
:class:`RunFacts`) into a :class:`Quality`: the overall ``verdict`` (the most
severe reason, ``ok`` when there is none), every ``reason`` with a message in
the user's terms, and the metrics the reasons make meaningless (``withheld``),
which the caller stores as None instead of showing.

To add a case: a row in :data:`VERDICTS` (code, severity, meaning, what it
withholds) and a check in :data:`CHECKS` returning a :class:`Reason` or None.
This module reduces images to facts (:func:`image_facts`) but imports nothing
of ``jobs``, ``service`` or ``renderers``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metrics.checks import finite_pixel_mask
from metrics.flip import LUMINANCE_WEIGHTS
from metrics.registry import verdict_keys

#: Above this fraction of non-finite pixels the error metrics are withheld;
#: at or below it they are averaged over the finite pixels and flagged.
NONFINITE_WITHHOLD_FRACTION = 0.01
#: A reference pixel this dim (absolute luminance) or dimmer counts as black; a
#: negative pixel is not black (negative-radiance tells it).
BLACK_LUMINANCE = 1e-8
#: A reference with more than this fraction of black pixels is degenerate.
DEGENERATE_BLACK_FRACTION = 0.99

#: Metric name -> the prefixes of the stored keys it covers (aggregated and per seed),
#: e.g. "rbias2" covers rbias2, rbias2_raw and the noise floor it subtracts.
METRIC_KEYS: dict[str, tuple[str, ...]] = verdict_keys()  # from metrics.registry
ERROR_METRICS = tuple(METRIC_KEYS)
# A (nearly) black reference: relative errors, FLIP and the PSNR of two almost
# black tone-mapped images compare noise with nothing.
RELATIVE_METRICS = ("mrse", "rbias2", "rvar", "flip", "efficiency", "psnr")


@dataclass(frozen=True)
class VerdictCode:
    """One row of the verdict table."""

    code: str
    severity: int               # the overall verdict is the reason of highest severity
    meaning: str                # what the code says, for documentation and tooltips
    withholds: tuple[str, ...]  # metrics it makes meaningless (when it applies in full)


VERDICTS: dict[str, VerdictCode] = {v.code: v for v in (
    VerdictCode("ok", 0, "nothing found that makes the metrics meaningless", ()),
    VerdictCode("undertrained-cache", 5, "a cache took fewer successful training steps "
                "than its configuration needs to count as trained: the errors measure a cache "
                "early in its training", ()),
    VerdictCode("untrained-cache", 10, "a cache took no successful training step: the "
                "method ran, but not as intended", ()),
    VerdictCode("nonfinite-value", 15, "a metric, a statistic or a training loss came out "
                "NaN or infinite; it is stored as null and named", ()),
    VerdictCode("nonfinite", 20, "the render has NaN or infinite pixels", ERROR_METRICS),
    VerdictCode("negative-radiance", 30, "the reference has negative values (the scene emits "
                "or reflects negative radiance): FLIP's tone mapping is undefined for them",
                ("flip",)),
    VerdictCode("degenerate-reference", 40, "the reference is black (almost) everywhere: "
                "relative errors and FLIP compare noise with nothing", RELATIVE_METRICS),
    VerdictCode("no-emitter", 50, "the scene has no emitter: every image is black and "
                "every error trivially zero", ERROR_METRICS),
)}


@dataclass(frozen=True)
class Reason:
    """Why a run is not plainly ``ok``: a code of :data:`VERDICTS` and a message."""

    code: str
    message: str
    withheld: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"code": self.code, "message": self.message, "withheld": list(self.withheld)}


@dataclass(frozen=True)
class RunFacts:
    """What the verdict is decided from; counts are pixels of one (H, W) image."""

    pixels: int                              # H * W
    renders: int                             # K images evaluated
    nonfinite_pixels: int                    # non-finite pixels summed over the K renders
    reference_nonfinite_pixels: int = 0      # mean or variance non-finite (metrics skip them)
    reference_variance_nonfinite_pixels: int = 0  # of those: mean finite, variance not
    reference_black_pixels: int = 0          # |luminance| <= BLACK_LUMINANCE
    reference_negative_pixels: int = 0       # some channel < 0
    render_negative_pixels: int = 0          # summed over the K renders
    emitter_count: int | None = None         # None: not known
    nonfinite_values: tuple[str, ...] = ()   # paths of NaN/Inf metrics or losses, stored null
    cache_steps: tuple[int, ...] = ()        # per render's cache (empty: no cache)
    cache_skipped_steps: tuple[int, ...] = ()
    cache_min_steps: tuple[int, ...] = ()    # steps each cache needs to count as trained
    cache_records: tuple[int, ...] = ()      # usable training records per cache
    cache_dropped_nonfinite: tuple[int, ...] = ()  # records dropped: non-finite target/input

    @property
    def nonfinite_fraction(self) -> float:
        return self.nonfinite_pixels / max(1, self.pixels * self.renders)


@dataclass(frozen=True)
class Quality:
    """The verdict of a run (see the module docstring)."""

    verdict: str
    reasons: tuple[Reason, ...] = field(default_factory=tuple)
    withheld: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "reasons": [r.to_json() for r in self.reasons],
                "withheld": list(self.withheld)}


def _reason(code: str, message: str, withhold: bool = True) -> Reason:
    return Reason(code, message, VERDICTS[code].withholds if withhold else ())


def _percent(part: int, whole: int) -> str:
    return f"{100.0 * part / max(1, whole):.3g} %"


# ---- Checks: each looks at the facts and returns a reason or None ----

def _no_emitter(facts: RunFacts) -> Reason | None:
    if facts.emitter_count != 0:
        return None
    return _reason("no-emitter", "the scene has no emitter, so reference and render are black "
                                 "and an error of 0 would say nothing; errors withheld")


def _degenerate_reference(facts: RunFacts) -> Reason | None:
    if facts.reference_black_pixels <= DEGENERATE_BLACK_FRACTION * facts.pixels:
        return None
    return _reason("degenerate-reference",
                   f"{_percent(facts.reference_black_pixels, facts.pixels)} of the reference's "
                   f"pixels are black (luminance <= {BLACK_LUMINANCE:g}, limit "
                   f"{100 * DEGENERATE_BLACK_FRACTION:g} %): relative errors and FLIP withheld")


def _nonfinite(facts: RunFacts) -> Reason | None:
    total = facts.pixels * facts.renders
    if facts.nonfinite_pixels == 0 and facts.reference_nonfinite_pixels == 0:
        return None
    fraction = max(facts.nonfinite_fraction,
                   facts.reference_nonfinite_pixels / max(1, facts.pixels))
    parts = []
    if facts.nonfinite_pixels:
        parts.append(f"{facts.nonfinite_pixels} of {total} rendered pixels "
                     f"({_percent(facts.nonfinite_pixels, total)})")
    if facts.reference_nonfinite_pixels:
        ref = f"{facts.reference_nonfinite_pixels} of {facts.pixels} reference pixels"
        if facts.reference_variance_nonfinite_pixels:
            ref += (f" (in {facts.reference_variance_nonfinite_pixels} of them the "
                    "reference's variance overflowed: radiance too large for float32, "
                    "e.g. an emitter of 1e30)")
        parts.append(ref)
    where = " and ".join(parts)
    limit = f"{100 * NONFINITE_WITHHOLD_FRACTION:g} %"
    if fraction > NONFINITE_WITHHOLD_FRACTION:
        return _reason("nonfinite", f"{where} are NaN or infinite, above {limit}: errors "
                                    "withheld")
    return _reason("nonfinite", f"{where} are NaN or infinite (at most {limit}): errors are "
                                "over the finite pixels only", withhold=False)


def _nonfinite_values(facts: RunFacts) -> Reason | None:
    if not facts.nonfinite_values:
        return None
    shown = ", ".join(facts.nonfinite_values[:5])
    more = len(facts.nonfinite_values) - 5
    return _reason("nonfinite-value",
                   f"{len(facts.nonfinite_values)} values of the run were NaN or infinite and "
                   f"are stored as null (never averaged): {shown}"
                   + (f" and {more} more" if more > 0 else ""))


def _negative_radiance(facts: RunFacts) -> Reason | None:
    # Only the reference decides: a signed estimator (the two-level residual of unbiased
    # NIRC) legitimately averages to small negative pixels, which FLIP clamps to 0 like
    # any display would; a reference with negative radiance has no meaningful FLIP.
    if facts.reference_negative_pixels == 0:
        return None
    return _reason("negative-radiance",
                   f"negative values in {facts.reference_negative_pixels} reference pixels "
                   f"({facts.render_negative_pixels} rendered pixels): FLIP withheld")


def _untrained_cache(facts: RunFacts) -> Reason | None:
    untrained = sum(1 for steps in facts.cache_steps if steps == 0)
    if not untrained:
        return None
    skipped = sum(s for steps, s in zip(facts.cache_steps, facts.cache_skipped_steps,
                                        strict=False) if steps == 0)
    records = sum(r for steps, r in zip(facts.cache_steps, facts.cache_records, strict=False)
                  if steps == 0)
    dropped = sum(d for steps, d in zip(facts.cache_steps, facts.cache_dropped_nonfinite,
                                        strict=False) if steps == 0)
    if skipped:
        why = (f"all {skipped} steps they tried were skipped because the loss or its "
               "gradients were NaN or infinite (radiance too large for float32 training, "
               "e.g. an emitter of 1e30, or NaN training targets)")
    elif facts.cache_records and records == 0:
        why = (f"they received no usable training record ({dropped} dropped as NaN or "
               "infinite)")
    else:
        why = "no training step was attempted (too few frames or records)"
    return _reason("untrained-cache",
                   f"{untrained} of {len(facts.cache_steps)} caches took no successful training "
                   f"step: {why}; the cache answered untrained, so the errors measure an "
                   "untrained cache, not the method")


def _undertrained_cache(facts: RunFacts) -> Reason | None:
    # Caches that took no step at all are _untrained_cache's.
    short = [(steps, needed) for steps, needed in zip(facts.cache_steps, facts.cache_min_steps,
                                                      strict=False) if 0 < steps < needed]
    if not short:
        return None
    steps = ", ".join(str(s) for s, _ in short)
    needed = ", ".join(sorted({str(n) for _, n in short}))
    return _reason("undertrained-cache",
                   f"{len(short)} of {len(facts.cache_steps)} caches took fewer successful "
                   f"training steps ({steps}) than their configuration needs to count as "
                   f"trained ({needed}); the errors measure a cache early in its training: "
                   "pre-train it (pretrain_frames) or render more frames")


CHECKS: tuple[Callable[[RunFacts], Reason | None], ...] = (
    _no_emitter, _degenerate_reference, _nonfinite, _nonfinite_values, _negative_radiance,
    _untrained_cache, _undertrained_cache)


def assess(facts: RunFacts) -> Quality:
    """The verdict of a run from its facts: every reason found, most severe first."""
    reasons = sorted((r for check in CHECKS if (r := check(facts)) is not None),
                     key=lambda r: -VERDICTS[r.code].severity)
    if not reasons:
        return Quality("ok")
    withheld = {name for reason in reasons for name in reason.withheld}
    return Quality(reasons[0].code, tuple(reasons),
                   tuple(name for name in ERROR_METRICS if name in withheld))


def image_facts(image: np.ndarray) -> dict[str, int]:
    """Pixel counts of one (H, W, 3) image: non-finite, black (luminance), negative."""
    finite = finite_pixel_mask(image)
    values = np.where(finite[..., None], np.asarray(image, dtype=np.float64), 0.0)
    luminance = values @ LUMINANCE_WEIGHTS
    return {
        "pixels": int(finite.size),
        "nonfinite": int(np.count_nonzero(~finite)),
        "black": int(np.count_nonzero(finite & (np.abs(luminance) <= BLACK_LUMINANCE))),
        "negative": int(np.count_nonzero((values < 0).any(axis=-1))),
    }


def withhold(values: Mapping[str, Any], metrics: Iterable[str]) -> dict[str, Any]:
    """``values`` with every key of the withheld ``metrics`` (see METRIC_KEYS) set to None."""
    prefixes = tuple(p for name in metrics for p in METRIC_KEYS[name])
    return {key: None if prefixes and key.startswith(prefixes) else value
            for key, value in values.items()}
