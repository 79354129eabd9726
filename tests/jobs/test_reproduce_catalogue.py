"""The catalogue of the three papers' figures (jobs/reproduce/catalogue.py) against the
papers' data files and the registry: every data file parses with its required fields,
every figure the data speaks of is catalogued and every catalogued figure has a claim,
the registry's figures run and the others say what they need, docs/reproduce.md's
claims section is the data's, and `reproduce list` / a not-yet figure behave."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from unittest import mock

import pytest
from typer.testing import CliRunner

from jobs.reproduce import catalogue, registry
from jobs.reproduce.catalogue import CATALOGUE, claims_markdown, listing
from jobs.reproduce.papers import PaperClaim, PaperData, PaperValue, paper_data
from jobs.reproduce.registry import PAPERS, figures
from service.cli import app, main

ROOT = Path(__file__).resolve().parents[2]

#: The figures the three papers' results discuss, as the catalogue must cover them.
COVERAGE = {
    "vt": {"fig4", "fig5", "fig7", "fig9", "fig10", "fig11", "table1"},
    "nvc": {"fig1", "fig5", "fig6", "fig7", "fig9"},
    "nirc": {"fig4", "fig5", "fig6", "fig7", "table1", *(f"fig{n}" for n in range(8, 16))},
}


def test_every_data_file_parses_and_every_row_says_where_it_stands() -> None:
    for paper in PAPERS:
        data = paper_data(paper)
        assert data.claims, paper
        for row in [*data.values, *data.claims]:
            assert row.quote and (row.page is not None or row.section), (paper, row)
        for value in data.values:
            assert value.unit and value.device and value.resolution, (paper, value)
            assert value.source != "plot" or value.precision, (paper, value)
    # Planted: rows the schema must refuse.
    claim = paper_data("nvc").claims[0].model_dump()
    with pytest.raises(ValueError, match="page or its section"):
        PaperClaim.model_validate({**claim, "section": None, "page": None})
    value = paper_data("nvc").values[0].model_dump()
    with pytest.raises(ValueError, match="precision"):
        PaperValue.model_validate({**value, "source": "plot"})
    with pytest.raises(ValueError, match="unit"):
        PaperValue.model_validate({k: v for k, v in value.items() if k != "unit"})


def catalogue_gaps(entries: tuple[catalogue.CatalogueEntry, ...]) -> list[str]:
    """What is missing between the catalogue, the data files and the registry."""
    keys = {(e.paper, e.figure) for e in entries}
    gaps = [f"{k} listed twice" for k in keys if sum((e.paper, e.figure) == k
                                                    for e in entries) > 1]
    in_data = {(paper, row.figure) for paper in PAPERS
               for row in [*paper_data(paper).values, *paper_data(paper).claims]}
    gaps += [f"{k} in a data file, not catalogued" for k in sorted(in_data - keys)]
    gaps += [f"{k} catalogued without a claim" for k in sorted(keys - {
        (paper, c.figure) for paper in PAPERS for c in paper_data(paper).claims})]
    registered = {(f.paper, f.key) for f in figures()}
    gaps += [f"{k} registered, not catalogued" for k in sorted(registered - keys)]
    gaps += [f"{(e.paper, e.figure)} says nothing of what it needs" for e in entries
             if (e.paper, e.figure) not in registered and not e.needs]
    gaps += [f"{p}: {sorted(COVERAGE[p] ^ {e.figure for e in entries if e.paper == p})}"
             for p in COVERAGE if COVERAGE[p] != {e.figure for e in entries if e.paper == p}]
    return gaps


@pytest.fixture
def not_yet(monkeypatch: pytest.MonkeyPatch) -> catalogue.CatalogueEntry:
    """A catalogued figure taken out of the registry for the test: every figure runs."""
    figures()
    entry = CATALOGUE[-1]
    monkeypatch.delitem(registry._FIGURES, (entry.paper, entry.figure))
    return entry


def test_the_catalogue_the_data_files_and_the_registry_agree(
        not_yet: catalogue.CatalogueEntry) -> None:
    assert catalogue_gaps(CATALOGUE) == []
    # Planted: a figure dropped from the catalogue, one whose needs are lost.
    assert catalogue_gaps(CATALOGUE[1:]), "a dropped figure went unnoticed"
    not_yet = CATALOGUE.index(not_yet)
    blanked = (*CATALOGUE[:not_yet], type(CATALOGUE[not_yet])(
        **{**CATALOGUE[not_yet].__dict__, "needs": ""}), *CATALOGUE[not_yet + 1:])
    assert catalogue_gaps(blanked), "a not-yet figure without its needs went unnoticed"


def test_the_docs_claims_section_is_generated_from_the_data(
        monkeypatch: pytest.MonkeyPatch) -> None:
    doc = (ROOT / "docs" / "reproduce.md").read_text()
    begin, end = "<!-- claims:begin -->\n", "\n<!-- claims:end -->"
    assert begin in doc and end in doc, "docs/reproduce.md lost the claims markers"
    section = doc[doc.index(begin) + len(begin):doc.index(end)]
    assert section == claims_markdown(), ("docs/reproduce.md's claims are stale: replace "
                                          "them with `python -m jobs.reproduce.catalogue`")
    rows = listing()
    for row in rows:
        for claim in row["claims"]:
            assert f"| {claim['quote']} |" in section.replace("\\|", "|")
            assert claim["verdict"] != "not yet run" or row["status"] == "not yet"
    # Planted: verdicts changed in the data no longer match the docs.
    def changed(paper: str) -> PaperData:
        data = paper_data(paper)
        return data.model_copy(update={"claims": [
            c.model_copy(update={"verdict": "does not hold"}) if c.verdict else c
            for c in data.claims]})

    monkeypatch.setattr(catalogue, "paper_data", changed)
    assert claims_markdown() != section


def test_list_prints_every_figure_with_its_status_and_claims(
        not_yet: catalogue.CatalogueEntry) -> None:
    result = CliRunner().invoke(app, ["reproduce", "list", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert [(r["paper"], r["figure"]) for r in rows] == [(e.paper, e.figure)
                                                        for e in CATALOGUE]
    for row in rows:
        runs = row["status"] == "runs"
        assert bool(row["command"]) == runs and bool(row["needs"]) != runs, row
        assert row["claims"] and (row["quick"] is not None) == runs, row
    text = CliRunner().invoke(app, ["reproduce", "list"]).output
    assert "not yet: needs" in text and "runs: nirc-bench reproduce vt fig7" in text


def test_a_not_yet_figure_exits_2_saying_what_it_needs(
        capsys, data_folder: Path, not_yet: catalogue.CatalogueEntry) -> None:
    entry = not_yet
    argv = ["nirc-bench", "reproduce", entry.paper, entry.figure, "--data-dir",
            str(data_folder)]
    with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"{entry.paper} {entry.figure} is not reproduced yet: it needs {entry.needs}" in err
