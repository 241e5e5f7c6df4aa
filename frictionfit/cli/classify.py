"""``frictionfit features|train|predict|evaluate``: (placeholders until they land)."""

from __future__ import annotations

import typer


def features() -> None:
    """Not written yet."""
    raise typer.Exit(2)


def train() -> None:
    """Not written yet."""
    raise typer.Exit(2)


def predict() -> None:
    """Not written yet."""
    raise typer.Exit(2)


def evaluate() -> None:
    """Not written yet."""
    raise typer.Exit(2)
