"""Options several commands share take one default everywhere."""

from __future__ import annotations

import typer

from jobs.pareto.plan import ParetoSpec
from jobs.protocol.spec import ReferenceSpec
from service.cli import app


def _defaults(option: str) -> dict[str, object]:
    """Each command (and sub-command) taking ``option``, with its default."""
    found: dict[str, object] = {}

    def walk(command, path: str) -> None:
        for param in command.params:
            if option in getattr(param, "opts", ()):
                found[path] = param.default
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, f"{path} {name}".strip())

    walk(typer.main.get_command(app), "")
    return found


def test_every_command_scores_against_the_same_default_reference():
    """render, sweep, report and pareto each default to the reference spec's spp (pareto
    used 1024 while render used 4096: their results were scored against different
    references); the pareto plan's own default too."""
    defaults = _defaults("--ref-spp")
    assert {"render", "sweep", "report", "pareto"} <= set(defaults), defaults
    assert set(defaults.values()) == {ReferenceSpec().spp}, defaults
    assert ParetoSpec.__dataclass_fields__["ref_spp"].default == ReferenceSpec().spp
