"""The papers' published numbers and claims (``papers/<paper>.toml``; the file's header
says what each field means)."""

from __future__ import annotations

import tomllib
from functools import cache
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from jobs.reproduce.registry import PAPERS, ReproduceError

PAPERS_DIR = Path(__file__).parent / "papers"


class _Row(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    figure: str = Field(min_length=1)
    page: int = Field(ge=1, description="the paper's page, from 1")
    quote: str = Field(min_length=1, description="the table row or sentence as printed")


class PaperValue(_Row):
    """One number the paper prints in a table or plots in a figure."""

    scene: str
    series: str = Field(description="the policy: var-bound, mse-min, area-spread, pt")
    parameter: str | None = None
    setting: float | None = None
    quantity: str
    value: float
    unit: str
    source: Literal["table", "plot"] = Field(description="'plot': read off a plot by eye")


class PaperClaim(_Row):
    """A sentence the paper states about a figure."""


class PaperData(BaseModel):
    values: list[PaperValue]
    claims: list[PaperClaim]

    def of(self, figure: str) -> tuple[list[PaperValue], list[PaperClaim]]:
        return ([v for v in self.values if v.figure == figure],
                [c for c in self.claims if c.figure == figure])


@cache
def paper_data(paper: str) -> PaperData:
    """The data file of ``paper`` (a key of registry.PAPERS), validated."""
    if paper not in PAPERS:
        raise ReproduceError(f"unknown paper '{paper}'; choose one of {sorted(PAPERS)}")
    raw: dict[str, Any] = tomllib.loads((PAPERS_DIR / PAPERS[paper].data_file).read_text())
    return PaperData(values=raw.get("value", []), claims=raw.get("claim", []))
