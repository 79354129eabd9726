"""The papers' published numbers and claims (``papers/<paper>.toml``; the file's header
says what each field means)."""

from __future__ import annotations

import tomllib
from functools import cache
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from jobs.reproduce.registry import PAPERS, ReproduceError

PAPERS_DIR = Path(__file__).parent / "papers"


class _Row(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    figure: str = Field(min_length=1)
    page: int | None = Field(None, ge=1, description="the paper's page, from 1")
    section: str | None = Field(None, min_length=1,
                                description="the section or caption ('4.1', 'Figure 5') "
                                            "where the text copy has no page numbers")
    quote: str = Field(min_length=1, description="the table row or sentence as printed")

    @model_validator(mode="after")
    def _located(self) -> _Row:
        if self.page is None and self.section is None:
            raise ValueError(f"{self.figure}: a row needs its page or its section")
        return self


class PaperValue(_Row):
    """One number the paper prints in a table or plots in a figure."""

    scene: str
    series: str = Field(description="the method or policy (var-bound, nirc biased, ...)")
    parameter: str | None = None
    setting: float | None = None
    quantity: str
    value: float
    unit: str
    source: Literal["table", "text", "plot"] = Field(
        description="'table': printed in a table; 'text': in a sentence or caption; "
                    "'plot': read off a plot by eye")
    precision: float | None = Field(None, gt=0, description="a plot reading's precision, "
                                                            "+- in the value's unit")
    device: str | None = Field(None, description="the paper's GPU for this number")
    resolution: str | None = Field(None, description="the paper's image size, e.g. 1920x1080")

    @model_validator(mode="after")
    def _plot_readings_say_how_precise(self) -> PaperValue:
        if self.source == "plot" and self.precision is None:
            raise ValueError(f"{self.figure}: a value read off a plot needs its precision")
        return self


class PaperClaim(_Row):
    """A sentence the paper states about a figure, and today's verdict on it where one
    of our measurements has judged it (with where that measurement is written up)."""

    verdict: str | None = None


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
