"""Every option of every nirc-bench command says what it is in --help (report's --frames,
--seeds and --pretrain, serve's --host and --port, ... showed only their defaults)."""

from __future__ import annotations

import typer.main

from service.cli import app


def options_without_help(command, prefix: str = "") -> list[str]:
    """'COMMAND --option' for each option of ``command`` and its subcommands that has no
    help text."""
    if hasattr(command, "commands"):
        return [found for name, sub in command.commands.items()
                for found in options_without_help(sub, f"{prefix}{name} ")]
    return [f"{prefix.strip()} {param.opts[0]}" for param in command.params
            if getattr(param, "param_type_name", "") == "option" and not param.help]


def test_every_option_of_every_command_has_help():
    command = typer.main.get_command(app)
    assert options_without_help(command) == []
    # Planted: an option without help is named.
    report = command.commands["report"]
    frames = next(param for param in report.params if param.name == "frames")
    saved, frames.help = frames.help, None
    try:
        assert options_without_help(command) == ["report --frames"]
    finally:
        frames.help = saved
