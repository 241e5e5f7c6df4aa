"""``frictionfit bench``: (placeholder until it lands)."""

from __future__ import annotations

import typer


def bench() -> None:
    """Not written yet."""
    raise typer.Exit(2)
