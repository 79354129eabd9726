"""The colour and dash of each series on a chart, the same rule for the dashboard's
Vega-Lite charts (jobs/views/charts.py) and the PNG figures (jobs/views/plots.py).

* **One hue per method family** (the method: ``pt``, ``nirc``, ...), fixed in
  :data:`FAMILY_COLOURS`, so a family has one hue on every page, chart and file. The hues
  are Tableau's categorical palette (Vega's ``tableau10``, then ``tableau20``'s light
  variants for the methods that are compared in other charts than the hue's dark twin);
  none is grey or black, which are the Pareto front's (:data:`FRONT_COLOUR`).
* **Shades and dashes for a family's configurations** (a family's series on one chart,
  e.g. the paper's PT and PT with throughput roulette, or N_c 8 and N_c 16): the first
  configuration has the family's hue, solid; the k-th of n is that hue darkened toward
  black by ``MAX_DARKEN * k / (n - 1)`` and drawn with the k-th dash pattern.
* A family not in the table (a method this code does not register, a label without
  a method) takes the first colour of :data:`SPARE_COLOURS` no other family of the
  chart has.

* The strongest PT's envelope (the best of its candidates at each time,
  jobs/views/envelope.py) is one series of its own, :data:`ENVELOPE_STYLE`: grey (no
  family's hue), drawn wide and translucent under its candidates' curves, so it is never
  mistaken for a candidate or for the black front.

So every series of a chart has its own colour, and two families never share a hue.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

#: Family hue by method, every registered method (a test checks the list is complete).
FAMILY_COLOURS = {
    "pt": "#f28e2b",            # orange
    "pt-power": "#76b7b2",      # teal
    "pt-spatial": "#ff9da7",    # pink
    "nirc": "#e15759",          # red (the NIRC paper's)
    "nrc": "#4e79a7",           # blue (the NIRC paper's)
    "grid-cache": "#59a14f",    # green
    "nirc-nvc-env": "#b07aa1",  # purple
    "nvc-env": "#9c755f",       # brown
    "nvc-lights": "#edc948",    # yellow
    # Direct-light methods, compared among themselves (many-lights, max_depth 2):
    "restir-di": "#d4a6c8",     # light purple
    "restir-nvc": "#8cd17d",    # light green
    "neural-di": "#a0cbe8",     # light blue
    "nrc-di": "#d7b5a6",        # light brown
    # Control variates at first hits (the NIRC paper's Sec. 6.1 comparison):
    "cv-sh": "#499894",         # dark teal
    "cv-vmf": "#b6992d",        # olive
    "ss-nirc": "#ff9d9a",       # light red (screen-space NIRC, beside nirc)
    "ncv": "#17becf",           # cyan (neural control variate)
}
#: Hues for families not in the table: the rest of Tableau 20 and Vega's category10.
SPARE_COLOURS = ("#ffbe7d", "#86bcb6", "#f1ce63", "#fabfd2", "#1f77b4",
                 "#2ca02c", "#9467bd", "#17becf", "#bcbd22", "#e377c2", "#8c564b")
FRONT_COLOUR = "#000000"
#: How far toward black the last configuration of a family is darkened.
MAX_DARKEN = 0.4
#: Dash patterns (on, off, ... in points) of a family's configurations; () is solid.
DASHES: tuple[tuple[int, ...], ...] = ((), (6, 3), (2, 2), (8, 3, 2, 3), (4, 4),
                                       (1, 3), (10, 4))


@dataclass(frozen=True)
class SeriesStyle:
    colour: str
    dash: tuple[int, ...]

    @property
    def vega_dash(self) -> list[int]:
        """Vega's strokeDash: [1, 0] draws solid."""
        return list(self.dash) or [1, 0]


#: The strongest PT's envelope (module docstring): its colour and dash, its line width
#: (points in the PNG figures, pixels in the Vega-Lite charts) and opacity.
ENVELOPE_STYLE = SeriesStyle("#7f7f7f", ())
ENVELOPE_WIDTH = 7.0
ENVELOPE_OPACITY = 0.4


def darken(colour: str, fraction: float) -> str:
    """``colour`` (#rrggbb) mixed with black: ``fraction`` 0 keeps it, 1 is black."""
    channels = (int(colour[i:i + 2], 16) for i in (1, 3, 5))
    return "#" + "".join(f"{round(c * (1.0 - fraction)):02x}" for c in channels)


def family_hues(families: Iterable[str]) -> dict[str, str]:
    """The hue of each family of one chart: its own, or the first spare one left."""
    ordered = list(dict.fromkeys(families))
    taken = {FAMILY_COLOURS[f] for f in ordered if f in FAMILY_COLOURS}
    spare = iter(c for c in SPARE_COLOURS if c not in taken)
    hues = {}
    for family in ordered:
        hue = FAMILY_COLOURS.get(family) or next(spare, None)
        if hue is None:
            raise ValueError(f"more than {len(SPARE_COLOURS)} unknown method families "
                             "on one chart: no distinct colour left")
        hues[family] = hue
    return hues


def series_styles(series: Iterable[tuple[str, str]]) -> dict[str, SeriesStyle]:
    """The style of each series label of one chart from its (family, label) pairs: the
    family's hue, shaded and dashed by the label's place among the family's labels (the
    family's own name first, then alphabetical)."""
    by_family: dict[str, set[str]] = {}
    for family, label in series:
        by_family.setdefault(family, set()).add(label)
    hues = family_hues(sorted(by_family))
    styles = {}
    for family, labels in by_family.items():
        ordered = sorted(labels, key=lambda label: (label != family, label))
        for k, label in enumerate(ordered):
            shade = MAX_DARKEN * k / (len(ordered) - 1) if len(ordered) > 1 else 0.0
            styles[label] = SeriesStyle(darken(hues[family], shade), DASHES[k % len(DASHES)])
    return styles
