"""``frictionfit simulate``: (placeholder until the simulator lands)."""

from __future__ import annotations

import typer

app = typer.Typer(help="Simulate rubbing measurements or touch gestures with known truth.")
