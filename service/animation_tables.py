"""What the CLI prints of an animated run (docs/animation.md): the per-frame error, the
recovery after each change and the scene-update stage, from the run's
``metrics['animation']`` (jobs.protocol.animation)."""

from __future__ import annotations

from typing import Any

from rich.console import Group
from rich.table import Table

#: The key of an animated run's metrics (jobs.protocol.animation.execute_animated).
ANIMATION_KEY = "animation"


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def segment_bounds(changes: list[int], frames: int) -> list[tuple[int, int]]:
    """(first, last) frame of each segment: frames between two change points."""
    starts = [0, *(change for change in changes if 0 < change < frames)]
    return [(start, end - 1) for start, end in zip(starts, [*starts[1:], frames], strict=True)]


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


def animation_tables(animation: dict[str, Any]) -> Group:
    """The per-frame error, the recovery times and the scene-update cost of a run."""
    if animation.get("frame_mrse") is None:
        parts: list[Any] = [f"animation: {animation.get('note', 'no per-frame error')}"]
    else:
        parts = [frame_error_table(animation), recovery_table(animation)]
    parts.append(scene_update_line(animation["scene_update"]))
    return Group(*parts)
