"""Two animated runs side by side (docs/animation.md, "Comparing runs"): per change both
runs' frames to recover with their bootstrap intervals, and whether they differ (the
intervals are disjoint); per segment both runs' steady error, the mean of the seed-mean
error over the segment's last ``steady_frames`` frames (all of them in a shorter one);
both runs' flicker with its interval and whether they differ (e.g. a cache against PT
at the same spp: jobs.protocol.flicker). Runs of different animations, or an animated
run beside a static one, are not comparable frame by frame: the comparison says so and
lists nothing."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import BaseModel

#: The key of an animated run's metrics (jobs.protocol.animation.execute_animated).
ANIMATION_KEY = "animation"


class RunRecovery(BaseModel):
    """One run's recovery after a change: frames with the bootstrap interval, or why none."""

    frames: int | None
    low: float | None
    high: float | None
    steady_error: float | None
    note: str | None = None


class ChangeComparison(BaseModel):
    change_frame: int
    label: str
    baseline: RunRecovery
    run: RunRecovery
    differs: bool | None     # the intervals are disjoint; None where one has none


class SegmentSteady(BaseModel):
    first: int
    last: int
    baseline: float
    run: float


class RunFlicker(BaseModel):
    """One run's flicker: the seed mean with its interval, or why none."""

    mean: float | None
    low: float | None
    high: float | None
    note: str | None = None


class FlickerComparison(BaseModel):
    baseline: RunFlicker
    run: RunFlicker
    differs: bool | None     # the intervals are disjoint; None where one has none


class AnimationDelta(BaseModel):
    """An animated run against the baseline (or why the two are not comparable)."""

    run: int
    baseline: int
    comparable: bool
    note: str
    changes: list[ChangeComparison] = []
    segments: list[SegmentSteady] = []
    #: None where a run was stored before flicker was measured
    flicker: FlickerComparison | None = None


def segment_bounds(changes: list[int], frames: int) -> list[tuple[int, int]]:
    """(first, last) frame of each segment: frames between two change points."""
    starts = [0, *(change for change in changes if 0 < change < frames)]
    return [(start, end - 1) for start, end in zip(starts, [*starts[1:], frames], strict=True)]


def _recovery(found: Mapping[str, Any] | None) -> RunRecovery:
    if found is None or "note" in found:
        return RunRecovery(frames=None, low=None, high=None, steady_error=None,
                           note=(found or {}).get("note", "not measured"))
    return RunRecovery(frames=found["frames"], low=found["low"], high=found["high"],
                       steady_error=found["steady_error"])


def _flicker(found: Mapping[str, Any]) -> RunFlicker:
    return RunFlicker(mean=found.get("mean"), low=found.get("low"), high=found.get("high"),
                      note=found.get("note"))


def disjoint(a: RunRecovery | RunFlicker, b: RunRecovery | RunFlicker) -> bool | None:
    if None in (a.low, a.high, b.low, b.high):
        return None
    return bool(a.high < b.low or b.high < a.low)


def steady_error(mean: list[float], first: int, last: int, steady_frames: int) -> float:
    return float(np.mean(mean[max(first, last - steady_frames + 1):last + 1]))


def _not_comparable(run_id: int, baseline_id: int, why: str) -> AnimationDelta:
    return AnimationDelta(run=run_id, baseline=baseline_id, comparable=False,
                          note=f"not comparable frame by frame: {why}")


def compare_animations(baseline_id: int, baseline_metrics: Mapping[str, Any], run_id: int,
                       run_metrics: Mapping[str, Any]) -> AnimationDelta | None:
    """Run ``run_id`` against ``baseline_id`` from their stored metrics (module docstring);
    None when neither is animated."""
    base, other = baseline_metrics.get(ANIMATION_KEY), run_metrics.get(ANIMATION_KEY)
    if base is None and other is None:
        return None
    if base is None or other is None:
        animated, static = (run_id, baseline_id) if base is None else (baseline_id, run_id)
        return _not_comparable(run_id, baseline_id,
                               f"run {animated} is animated, run {static} static")
    if base["digest"] != other["digest"]:
        return _not_comparable(run_id, baseline_id, "the runs' scenes change differently")
    curves = (base.get("frame_mrse"), other.get("frame_mrse"))
    if None in curves:
        return _not_comparable(run_id, baseline_id, "a run stored no per-frame error "
                                                    "(a frame's error is NaN or infinite)")
    if len(curves[0]["mean"]) != len(curves[1]["mean"]):
        return _not_comparable(run_id, baseline_id, "the runs have different frame counts")
    labels = dict(zip(base["change_frames"], base.get("change_labels") or (), strict=False))
    found = [{r["change_frame"]: r for r in m["recovery"] or ()} for m in (base, other)]
    changes = []
    for frame in found[0].keys() | found[1].keys():
        a, b = _recovery(found[0].get(frame)), _recovery(found[1].get(frame))
        changes.append(ChangeComparison(change_frame=frame,
                                        label=labels.get(frame, f"change at frame {frame}"),
                                        baseline=a, run=b, differs=disjoint(a, b)))
    steady_frames = base["recovery_rule"]["steady_frames"]
    segments = [SegmentSteady(first=first, last=last,
                              baseline=steady_error(curves[0]["mean"], first, last, steady_frames),
                              run=steady_error(curves[1]["mean"], first, last, steady_frames))
                for first, last in segment_bounds(base["change_frames"],
                                                  len(curves[0]["mean"]))]
    flicker = None
    if "flicker" in base and "flicker" in other:
        a, b = _flicker(base["flicker"]), _flicker(other["flicker"])
        flicker = FlickerComparison(baseline=a, run=b, differs=disjoint(a, b))
    return AnimationDelta(run=run_id, baseline=baseline_id, comparable=True,
                          note="recovery intervals: percentile bootstrap over seeds; flicker "
                               "intervals: Student t over seeds; they differ where they are "
                               "disjoint",
                          changes=sorted(changes, key=lambda c: c.change_frame),
                          segments=segments, flicker=flicker)
