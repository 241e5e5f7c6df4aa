"""``frictionfit info``: summarise a recording or a folder of recordings."""

from __future__ import annotations

from pathlib import Path

import typer


def info(
    path: Path = typer.Argument(..., help="A recording (<name>.csv / .json / stem) or a folder."),
) -> None:
    """Print channels, duration, events, metadata and problems of a recording or dataset."""
    from collections import Counter

    from frictionfit.errors import FrictionfitError
    from frictionfit.recording import read_dataset, read_recording

    try:
        if path.is_dir():
            recs = read_dataset(path)
            labels = Counter(str(r.label) for r in recs)
            damaged = sum(1 for r in recs if any(p.kind != "gap" for p in r.problems))
            typer.echo(f"{path}: {len(recs)} recordings, {len(labels)} labels, {damaged} flagged")
            typer.echo(f"channels: {', '.join(f'{c.name} [{c.unit}]' for c in recs[0].channels)}")
            for label, n in sorted(labels.items()):
                typer.echo(f"  {label}: {n}")
            return
        rec = read_recording(path, on_error="flag")
    except FrictionfitError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(f"{rec.name}: {rec.n_samples} samples, {rec.duration_s:.3f} s "
               f"at {rec.sample_rate_hz:g} Hz")
    typer.echo(f"channels: {', '.join(f'{c.name} [{c.unit}]' for c in rec.channels)}")
    typer.echo(f"events: {len(rec.events)}" + (
        f" (first {rec.events[0].kind} {rec.events[0].target} at {rec.events[0].t:g} s)"
        if rec.events else ""))
    typer.echo(f"metadata: {rec.metadata}")
    if rec.extra:
        typer.echo(f"other sidecar keys: {sorted(rec.extra)}")
    for p in rec.problems:
        typer.echo(f"problem [{p.kind}]: {p}")
