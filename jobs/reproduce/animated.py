"""Figures over animated runs: a method's frames rendered one by one under an animation
(jobs.protocol.animation), read back as each frame's seed-mean error with its interval,
the frames to recover after a change, the flicker and the median frame time."""

from __future__ import annotations

from typing import Any

from jobs.reproduce.registry import Context
from jobs.reproduce.results import Estimate, Point

CURVE_NOTE = "MRSE, FLIP: 95 % Student-t interval over the K seeds, frame by frame"
RECOVERY_NOTE = ("frames until the seed-mean MRSE stays within 10 % of the segment's steady "
                 "error; 95 % interval: percentile bootstrap over the seeds")


def stored_run(ctx: Context, spec: Any, figure: str | None = None) -> Any:
    """The run of ``spec`` (a ``RenderSpec`` with its animation), rendered unless one is
    stored: with ``figure``, the run stored under that name (a figure's, or one shared by
    figures rendering the same runs), the spec's key (the spec under today's versions)
    and this CPU, whatever commit made it; without, one of
    exactly this spec by this commit (jobs.protocol.executor.find_same_run). Counted in
    ``ctx.work`` as a point reused or rendered."""
    from jobs.protocol.executor import execute
    from jobs.protocol.job import RenderJob
    from renderers.backend import cpu_device_key
    from renderers.seeding import digest

    key = (None if figure is None
           else digest(f"reproduce-{figure}", spec.key(), cpu_device_key(), length=32))
    run = None if key is None else ctx.store.find_run_by_idempotency_key(key)
    if run is None:
        summary = execute(RenderJob.parse(spec), ctx.store, ctx.settings, progress=ctx.progress,
                          idempotency_key=key, reuse=key is None)
        reused = summary.reused
        run = ctx.store.get_run(summary.run_id)
    else:
        reused = True
    name = "points_reused" if reused else "points_rendered"
    ctx.work[name] = ctx.work.get(name, 0) + 1
    return run


def curve_point(scene: str, series: str, frame: int, animation: dict[str, Any]) -> Point:
    """One frame's seed-mean MRSE and FLIP with their intervals (``animation``: a run's
    ``metrics["animation"]``)."""
    values = {}
    for key, stored in (("mrse", "frame_mrse"), ("flip", "frame_flip")):
        curve = animation.get(stored)
        if curve is None:
            values[key] = Estimate(value=None, note=animation.get("note"))
            continue
        interval = None if curve["low"] is None else [curve["low"][frame], curve["high"][frame]]
        values[key] = Estimate(value=curve["mean"][frame], ci95=interval, note=CURVE_NOTE)
    return Point(scene=scene, series=series, x=float(frame), values=values)


def ms_per_frame(run: Any) -> float | None:
    """The run's median frame time in ms (None where it has none)."""
    seconds = run.timings.get("seconds_per_frame")
    return None if seconds is None else 1e3 * seconds


def recovery_estimate(animation: dict[str, Any], change: int) -> Estimate:
    """The frames to recover after the change at frame ``change`` with their interval."""
    for found in animation.get("recovery") or []:
        if found["change_frame"] == change:
            if "frames" not in found:
                return Estimate(value=None, note=found.get("note"))
            interval = None if found["low"] is None else [found["low"], found["high"]]
            return Estimate(value=float(found["frames"]), ci95=interval, note=RECOVERY_NOTE)
    return Estimate(value=None, note="no recovery measured (a frame's error is not finite)")


def flicker_estimate(animation: dict[str, Any]) -> Estimate:
    """The run's flicker (docs/animation.md, "Flicker"), seed mean with its interval."""
    found = animation.get("flicker") or {}
    interval = None if found.get("low") is None else [found["low"], found["high"]]
    return Estimate(value=found.get("mean"), ci95=interval,
                    note=found.get("note") or "flicker: seed mean, 95 % Student-t interval")
