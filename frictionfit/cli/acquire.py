"""``frictionfit acquire|rub``: (placeholders until they land)."""

from __future__ import annotations

import typer


def acquire() -> None:
    """Not written yet."""
    raise typer.Exit(2)


def rub() -> None:
    """Not written yet."""
    raise typer.Exit(2)
