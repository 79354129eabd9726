"""The soak: every registered method, long enough to notice what short checks do not.

The stress suite renders adversarial scenes for a frame or two; a frozen replay that
corrupts memory, a recording that keeps being made or a cache whose weights drift to
NaN shows only after tens of frames. The soak renders every registered method on the
first of :data:`SCENES` it applies to, with its default parameters, through the code
path of ``nirc-bench render`` (a job run in a render process of its own,
jobs/execution/embedded.py: frozen frames, the warm-up, the executor, the store), and
fails a row when

* the render process died (a signal: heap corruption, a segmentation fault) or the
  job failed;
* a stored metric, a frame's error or a cache's loss or weight is not finite;
* a seed's frozen functions recorded again after the warm-up, beyond the recordings
  of frames whose buffers grew (``timings.frozen_seeds``: a caching frame records its
  passes anew for a larger buffer, by design; anything else means a replay met a width
  or value it was not recorded with, docs/timing.md "The width rule").

The default size (32x32, 64 frames x 4 seeds) takes at most 20 minutes on 2 cores;
``.ci/run`` and ``nirc-bench ci`` run a short form (:data:`SHORT`). The reference is
only what a job needs to run (``reference_spp`` samples): the soak checks survival
and finiteness, not agreement (the stress suite's agreement tests do that).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

from pydantic import BaseModel, Field

from jobs.stress.stress import count_nonfinite_values, stored_nonfinite, training_counts

#: The scenes a method is soaked on, the first it applies to.
SCENES = ("cornell-box", "many-lights", "sky")


class SoakSettings(BaseModel):
    resolution: int = Field(32, ge=4, le=512)
    frames: int = Field(64, ge=1, le=4096)
    seeds: int = Field(4, ge=1, le=64)
    reference_spp: int = Field(64, ge=8, le=1 << 20)


#: The short form run after the tests (``.ci/run``, ``nirc-bench ci``): at most 5 min.
SHORT = SoakSettings(resolution=16, frames=64, seeds=2)


class SoakRow(BaseModel):
    method: str
    scene: str | None
    #: 'ok' or 'failed' (the problems below; also a method no soak scene suits).
    status: str
    seconds: float | None = None
    problems: list[str] = Field(default_factory=list)
    #: Per seed: recordings after the warm-up, after the frames, and of buffer growth.
    recordings: list[list[int]] = Field(default_factory=list)


class SoakReport(BaseModel):
    settings: SoakSettings
    rows: list[SoakRow]

    def problems(self) -> list[str]:
        return [f"{row.method} on {row.scene}: {problem}"
                for row in self.rows for problem in row.problems]


def soak_scene(method: str, features_of: Callable[[str], Any]) -> tuple[str | None, str]:
    """The first soak scene ``method`` applies to (None and why not, if none)."""
    from renderers.methods import get_method

    reasons = []
    for scene in SCENES:
        applies, why = get_method(method).applies_to(features_of(scene))
        if applies:
            return scene, ""
        reasons.append(f"{scene}: {why}")
    return None, "; ".join(reasons)


def recording_problems(timings: dict[str, Any]) -> tuple[list[list[int]], list[str]]:
    """Each seed's (after warm-up, after frames, for growth) recordings, and a problem
    per seed that recorded again for another reason than its buffers' growth."""
    counts, problems = [], []
    for seed, frozen in enumerate(timings.get("frozen_seeds") or [timings.get("frozen")]):
        if not frozen:
            continue
        warm, after = frozen["recordings_after_warmup"], frozen["recordings_after_frames"]
        growth = frozen.get("recordings_for_growth", 0)
        counts.append([warm, after, growth])
        if after - warm > growth:
            problems.append(f"seed {seed}: {after - warm - growth} recording(s) after the "
                            f"warm-up not explained by buffer growth ({warm} -> {after}, "
                            f"{growth} for growth)")
    return counts, problems


def summary_problems(summary: Any) -> list[str]:
    """Non-finite values a finished run stored or reported (module doc)."""
    problems = []
    quality = summary.quality or {}
    stored_metrics, stored_losses = stored_nonfinite(quality)
    metrics = stored_metrics + count_nonfinite_values(summary.metrics) + sum(
        count_nonfinite_values({k: v for k, v in seed.items() if k != "method_stats"})
        for seed in summary.per_seed)
    if metrics:
        problems.append(f"{metrics} non-finite metric value(s)")
    if quality.get("nonfinite_pixels"):
        problems.append(f"{quality['nonfinite_pixels']} non-finite pixel value(s)")
    counts = training_counts(seed.get("method_stats") for seed in summary.per_seed)
    losses = (counts["nonfinite_losses"] or 0) + stored_losses
    if losses:
        problems.append(f"{losses} non-finite loss(es)")
    if counts["nonfinite_weights"]:
        problems.append(f"{counts['nonfinite_weights']} non-finite cache weight(s)")
    return problems


def run_soak(render: Callable[[Any], Any], features_of: Callable[[str], Any],
             settings: SoakSettings, methods: Iterable[str] | None = None,
             progress: Callable[[str], None] | None = None) -> SoakReport:
    """Soak ``methods`` (default: every registered one). ``render(job)`` runs a job as
    ``nirc-bench render`` does and returns its RunSummary, raising on a failed job (its
    message says why: a signal and the stage, or the error)."""
    from jobs.protocol.job import RenderJob
    from jobs.protocol.spec import ReferenceSpec, RenderSpec
    from renderers.methods import METHODS

    rows = []
    for method in METHODS if methods is None else methods:
        scene, why = soak_scene(method, features_of)
        if scene is None:
            # A method the soak cannot run is a gap in what it checks: said, and failed.
            rows.append(SoakRow(method=method, scene=None, status="failed", problems=[
                f"applies to none of the soak scenes ({why})"]))
            continue
        if progress:
            progress(f"{method} on {scene}")
        spec = RenderSpec(scene=scene, method=method, resolution=settings.resolution,
                          frames=settings.frames, seeds=settings.seeds,
                          reference=ReferenceSpec(spp=settings.reference_spp))
        start = time.perf_counter()
        try:
            summary = render(RenderJob.parse(spec))
        except Exception as err:  # noqa: BLE001 - a failed render is the row's finding
            rows.append(SoakRow(method=method, scene=scene, status="failed",
                                seconds=time.perf_counter() - start, problems=[str(err)]))
            continue
        recordings, problems = recording_problems(summary.timings)
        problems += summary_problems(summary)
        rows.append(SoakRow(method=method, scene=scene, status="failed" if problems else "ok",
                            seconds=time.perf_counter() - start, problems=problems,
                            recordings=recordings))
    return SoakReport(settings=settings, rows=rows)


def markdown_table(report: SoakReport) -> str:
    settings = report.settings
    lines = [f"Soak: {settings.resolution}x{settings.resolution}, {settings.frames} frames x "
             f"{settings.seeds} seeds per method", "",
             "| method | scene | status | s | recordings (warm-up -> end, growth) | problems |",
             "|---|---|---|---|---|---|"]
    for row in report.rows:
        counts = ", ".join(f"{w}->{a} ({g})" for w, a, g in row.recordings) or "–"
        seconds = "–" if row.seconds is None else f"{row.seconds:.0f}"
        lines.append(f"| {row.method} | {row.scene or '–'} | {row.status} | {seconds} | "
                     f"{counts} | {'; '.join(row.problems) or '–'} |")
    return "\n".join(lines)
