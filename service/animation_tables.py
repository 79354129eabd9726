"""What the CLI prints of an animated run (docs/animation.md): the per-frame error, the
recovery after each change, the flicker and the scene-update stage, from the run's
``metrics['animation']`` (jobs.protocol.animation)."""

from __future__ import annotations

from typing import Any

from rich.console import Group
from rich.table import Table

from jobs.views.animation_comparison import (
    AnimationDelta,
    RunFlicker,
    RunRecovery,
    segment_bounds,
)


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def frame_error_table(animation: dict[str, Any]) -> Table:
    """Each segment's first and last frame: the seed-mean MRSE with its 95 % interval."""
    curve = animation["frame_mrse"]
    mean, low, high = curve["mean"], curve["low"], curve["high"]
    table = Table(title=f"per-frame MRSE against each frame's reference (mean over "
                        f"{curve['seeds']} seeds; each segment's first and last frame)")
    for column in ("segment", "frame", "MRSE", "95% interval"):
        table.add_column(column, justify="right")
    for number, (first, last) in enumerate(segment_bounds(animation["change_frames"],
                                                          len(mean))):
        for frame in dict.fromkeys((first, last)):
            interval = "-" if low is None else f"[{_number(low[frame])}, {_number(high[frame])}]"
            table.add_row(str(number), str(frame), _number(mean[frame]), interval)
    return table


def recovery_table(animation: dict[str, Any]) -> Table:
    """Frames to recover after each change, with its bootstrap interval over seeds."""
    rule = animation["recovery_rule"]
    table = Table(title=f"recovery after each change (within {100 * rule['tolerance']:.0f} % "
                        f"of the steady error: the mean of a segment's last "
                        f"{rule['steady_frames']} frames)")
    for column in ("change at frame", "MRSE before", "MRSE at change", "steady MRSE",
                   "frames to recover", "95% interval"):
        table.add_column(column, justify="right")
    for found in animation["recovery"]:
        if "note" in found:
            table.add_row(str(found["change_frame"]), "-", "-", "-", found["note"], "-")
            continue
        frames = f"{found['frames']}{' (in the steady window)' if found['within_window'] else ''}"
        interval = ("-" if found["low"] is None
                    else f"[{found['low']:.3g}, {found['high']:.3g}]")
        table.add_row(str(found["change_frame"]), _number(found["error_before"]),
                      _number(found["error_at_change"]), _number(found["steady_error"]),
                      frames, interval)
    return table


def scene_update_line(update: dict[str, Any]) -> str:
    """The scene-update stage (outside the method's frame time) in one line."""
    if not update["updates"]:
        return "scene update: none during the run's frames"
    return (f"scene update (outside the frame time): {update['updates']} updates, "
            f"{1e3 * update['total_s']:.3g} ms in all, median {1e3 * update['median_s']:.3g} ms")


def flicker_line(flicker: dict[str, Any]) -> str:
    """The run's flicker (jobs.protocol.flicker) in one line, or why there is none."""
    static = flicker.get("static_fraction")
    region = ("" if static is None else
              f", static region {100 * static:.3g} % of the pixels (reference change within "
              f"{flicker['static_z']:g} sigma)")
    if flicker.get("mean") is None:
        return f"flicker: {flicker.get('note', 'none')}{region}"
    interval = ("" if flicker["low"] is None
                else f" [{_number(flicker['low'])}, {_number(flicker['high'])}]")
    return (f"flicker (relative squared frame-to-frame difference over the static region, "
            f"mean over {flicker['seeds']} seeds, 95% interval): "
            f"{_number(flicker['mean'])}{interval}{region}")


def animation_tables(animation: dict[str, Any]) -> Group:
    """The per-frame error, the recovery times, the flicker and the scene-update cost of a
    run (a run stored before flicker was measured has none)."""
    if animation.get("frame_mrse") is None:
        parts: list[Any] = [f"animation: {animation.get('note', 'no per-frame error')}"]
    else:
        parts = [frame_error_table(animation), recovery_table(animation)]
    if "flicker" in animation:
        parts.append(flicker_line(animation["flicker"]))
    parts.append(scene_update_line(animation["scene_update"]))
    return Group(*parts)


def _recovery_text(found: RunRecovery) -> str:
    if found.frames is None:
        return found.note or "-"
    interval = "" if found.low is None else f" [{found.low:.3g}, {found.high:.3g}]"
    return f"{found.frames}{interval}"


def animation_comparison_tables(delta: AnimationDelta) -> Group | str:
    """Per change both runs' frames to recover and whether they differ; per segment both
    runs' steady error (jobs/views/animation_comparison.py)."""
    if not delta.comparable:
        return f"animation, run {delta.run} against run {delta.baseline}: {delta.note}"
    runs = (f"run {delta.baseline}", f"run {delta.run}")
    changes = Table(title=f"recovery after each change, run {delta.run} against run "
                          f"{delta.baseline} (frames, 95% bootstrap interval)")
    for column in ("change at frame", "what changed", *runs, "differs"):
        changes.add_column(column, justify="left" if column == "what changed" else "right")
    for change in delta.changes:
        changes.add_row(str(change.change_frame), change.label, _recovery_text(change.baseline),
                        _recovery_text(change.run),
                        "-" if change.differs is None else "yes" if change.differs else "no")
    segments = Table(title="steady MRSE per segment (seed mean over its last frames)")
    for column in ("segment", "frames", *runs):
        segments.add_column(column, justify="right")
    for number, segment in enumerate(delta.segments):
        segments.add_row(str(number), f"{segment.first}-{segment.last}",
                         _number(segment.baseline), _number(segment.run))
    parts: list[Any] = [changes, segments]
    if delta.flicker is not None:
        found = delta.flicker
        differs = "-" if found.differs is None else "yes" if found.differs else "no"
        parts.append(f"flicker: {runs[0]} {_flicker_text(found.baseline)}, "
                     f"{runs[1]} {_flicker_text(found.run)}; differs: {differs}")
    return Group(*parts, f"note: {delta.note}")


def _flicker_text(found: RunFlicker) -> str:
    if found.mean is None:
        return found.note or "-"
    interval = "" if found.low is None else f" [{found.low:.3g}, {found.high:.3g}]"
    return f"{found.mean:.3g}{interval}"
