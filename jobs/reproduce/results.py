"""What a reproduced figure reports: our numbers with 95 % intervals, point by point,
beside the paper's; written as Markdown and JSON next to the figure's PNG, with its
provenance (commit, libraries, what it took)."""

from __future__ import annotations

import json
import math
from datetime import datetime
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, Field

#: A verdict's kind.
Kind = Literal["holds", "does not hold", "not comparable"]


def where(claim: dict[str, Any]) -> str:
    """A claim's place in the paper: its page, else its section or caption as given."""
    return f"p. {claim['page']}" if claim.get("page") else str(claim["section"])


class Estimate(BaseModel):
    """A number and its 95 % interval (None: none could be made; ``note`` says how or why)."""

    value: float | None
    ci95: list[float] | None = None
    note: str | None = None

    def text(self) -> str:
        if self.value is None or not math.isfinite(self.value):
            return "—"
        if self.ci95 is None:
            return f"{self.value:.3g}"
        lo, hi = self.ci95
        return f"{self.value:.3g} [{lo:.3g}, {hi:.3g}]"


def apart(a: Estimate, b: Estimate) -> int:
    """+1 when ``a``'s 95 % interval lies above ``b``'s, -1 below, 0 overlapping or
    without intervals."""
    if a.ci95 is None or b.ci95 is None:
        return 0
    return 1 if a.ci95[0] > b.ci95[1] else -1 if a.ci95[1] < b.ci95[0] else 0


def kind_of(resolved: list[bool], contrary: list[bool]) -> Kind:
    """A claim made of checks: "does not hold" when an interval contradicts one, "holds"
    when intervals settle every one, "not comparable" when some are left unsettled."""
    return ("does not hold" if any(contrary) else "holds" if all(resolved)
            else "not comparable")


class Point(BaseModel):
    """One point (a row of the table): a scene, a series and the swept value ``x``."""

    scene: str
    series: str
    x: float | None = None
    values: dict[str, Estimate]
    paper: dict[str, float] = Field(default_factory=dict,
                                    description="the paper's values of the same quantities")
    run_id: int | None = None


class Verdict(BaseModel):
    """Whether one of the paper's claims holds in our numbers."""

    claim: str                      # the claim, short
    verdict: Kind
    reason: str


class FigureTime(BaseModel):
    """What reproducing a figure took, measure and drawing included: wall seconds, CPU
    seconds (this process's user + system time, its threads' (Dr.Jit's) included, and
    that of the child processes it waited for) and the machine's 1-, 5- and 15-minute
    load averages at its start and its end (on a shared machine its seconds are read
    beside them)."""

    wall_s: float
    cpu_s: float
    load_start: list[float]
    load_end: list[float]

    def text(self) -> str:
        return (f"wall {self.wall_s:.1f} s, CPU {self.cpu_s:.1f} s (load "
                f"{self.load_start[0]:.2f} -> {self.load_end[0]:.2f})")


class Provenance(BaseModel):
    """Where a stored reproduction comes from (its ``provenance.json``): the service's job
    that ran it (None: the CLI), the mode, the code's commit, the libraries, when it
    finished and what it took (None: stored before times were recorded)."""

    job_id: int | None = None
    mode: str | None = None
    git_commit: str
    libraries: dict[str, str]
    finished_at: datetime
    time: FigureTime | None = None


class Reproduction(BaseModel):
    """A figure or table of a paper as measured here."""

    paper: str
    figure: str
    title: str
    mode: str
    settings: dict[str, Any] = Field(description="what was rendered: resolution, seeds, "
                                                 "frames, reference, grid preset, ...")
    x_label: str
    quantities: dict[str, str] = Field(description="quantity key -> column label, in order")
    points: list[Point]
    notes: list[str] = Field(default_factory=list)
    claims: list[dict[str, Any]] = Field(default_factory=list,
                                         description="the paper's quoted claims with pages")
    work: dict[str, int] = Field(default_factory=dict,
                                 description="points rendered now and read from the store")
    verdicts: list[Verdict] = Field(default_factory=list,
                                    description="per claim: does it hold here, and why")
    images: dict[str, Any] = Field(default_factory=dict, exclude=True,
                                   description="data a figure draws beside its plot (e.g. "
                                               "integrand images), not written to its table")

    def markdown(self) -> str:
        settings = ", ".join(f"{k} {v}" for k, v in self.settings.items())
        lines = [f"# {self.title}", "", f"Mode `{self.mode}`: {settings}.", ""]
        if self.work:
            lines += [f"Points rendered now: {self.work.get('points_rendered', 0)}, read "
                      f"from the store: {self.work.get('points_reused', 0)}.", ""]
        lines += [f"- {note}" for note in self.notes]
        if self.claims:
            lines += ["", "The paper's claims:", ""]
            lines += [f"- {where(c)}: \"{c['quote']}\"" for c in self.claims]
        if self.verdicts:
            lines += ["", "Verdicts:", ""]
            lines += [f"- {v.claim}: **{v.verdict}** ({v.reason})" for v in self.verdicts]
        paper_keys = [k for k in self.quantities if any(k in p.paper for p in self.points)]
        header = ["scene", "series", self.x_label, *self.quantities.values(),
                  *(f"paper: {self.quantities[k]}" for k in paper_keys)]
        lines += ["", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for p in self.points:
            cells = [p.scene, p.series, "—" if p.x is None else f"{p.x:g}",
                     *(p.values[k].text() if k in p.values else "—" for k in self.quantities),
                     *(f"{p.paper[k]:g}" if k in p.paper else "—" for k in paper_keys)]
            lines.append("| " + " | ".join(cells) + " |")
        notes = sorted({e.note for p in self.points for e in p.values.values() if e.note})
        if notes:
            lines += ["", "Intervals:", "", *(f"- {note}" for note in notes)]
        return "\n".join(lines) + "\n"

    def write(self, out_dir: Path) -> dict[str, Path]:
        """table.md and table.json in ``out_dir`` (the figure's PNG is drawn beside them)."""
        out_dir.mkdir(parents=True, exist_ok=True)
        paths = {"markdown": out_dir / "table.md", "json": out_dir / "table.json"}
        paths["markdown"].write_text(self.markdown())
        paths["json"].write_text(json.dumps(self.model_dump(mode="json"), indent=1) + "\n")
        return paths
