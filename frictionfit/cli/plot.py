"""``frictionfit plot``: (placeholder until it lands)."""

from __future__ import annotations

import typer


def plot() -> None:
    """Not written yet."""
    raise typer.Exit(2)
