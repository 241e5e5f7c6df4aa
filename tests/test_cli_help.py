"""Every command's --help reads whole at 80 columns and speaks of the product only."""

from __future__ import annotations

import re

import click
import pytest
import typer
from typer.testing import CliRunner

from frictionfit.cli import app

COMMANDS = [[], ["simulate", "gestures"],
            *[[c] for c in ("demo", "info", "plot", "fit", "features", "train", "predict",
                            "evaluate", "acquire", "rub", "bench", "simulate")]]


def _options(path: list[str]) -> list[str]:
    command = typer.main.get_command(app)
    for name in path:
        command = command.commands[name]
    return [opt for p in command.params if isinstance(p, click.Option) for opt in p.opts]


@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "frictionfit")
def test_help_at_80_columns_is_whole(path):
    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "80"}, terminal_width=80)
    assert result.exit_code == 0, result.output
    text = result.output
    assert "…" not in text and not re.search(r"\w\.\.\.$", text, re.M), text
    assert not re.search(r"\bissue\b|\bsession \d+\b|this session", text, re.I), text
    assert all(len(line) <= 80 for line in text.splitlines()), text
    for option in _options(path):
        assert option in text, (option, text)
