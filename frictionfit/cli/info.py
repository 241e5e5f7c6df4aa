"""``frictionfit info``: summarise a recording or a folder of recordings."""

from __future__ import annotations

from pathlib import Path

import typer


def _dataset(path: Path) -> None:
    from collections import Counter

    from frictionfit.recording import read_dataset

    recs = read_dataset(path)
    labels = Counter(str(r.label) for r in recs)
    sessions = sorted({r.metadata.get("session") for r in recs}, key=str)
    problems = Counter(p.kind for r in recs for p in r.problems)
    flagged = [r for r in recs if r.problems]
    typer.echo(f"{path}: {len(recs)} recordings, {len(labels)} labels, "
               f"{len(sessions)} session(s), {len(flagged)} with problems")
    typer.echo(f"channels: {', '.join(f'{c.name} [{c.unit}]' for c in recs[0].channels)}")
    per = Counter((str(r.label), r.metadata.get("session")) for r in recs)
    width = max(len(label) for label in labels)
    typer.echo(f"{'label':{width}s}  " + "  ".join(f"s{s}" for s in sessions) + "  total")
    for label in sorted(labels):
        cells = "  ".join(f"{per[(label, s)]:>{len(f's{s}')}d}" for s in sessions)
        typer.echo(f"{label:{width}s}  {cells}  {labels[label]:5d}")
    if problems:
        typer.echo("problems: " + ", ".join(f"{k} x{n}" for k, n in sorted(problems.items())))
        for r in flagged:
            typer.echo(f"  {r.name}: " + "; ".join(f"[{p.kind}] {p}" for p in r.problems))


def _recording(path: Path) -> None:
    from frictionfit.recording import read_recording

    rec = read_recording(path, on_error="flag")
    typer.echo(f"{rec.name}: {rec.n_samples} samples, {rec.duration_s:.3f} s "
               f"at {rec.sample_rate_hz:g} Hz")
    typer.echo(f"channels: {', '.join(f'{c.name} [{c.unit}]' for c in rec.channels)}")
    typer.echo(f"events: {len(rec.events)}" + (
        f" (first {rec.events[0].kind} {rec.events[0].target} at {rec.events[0].t:g} s)"
        if rec.events else ""))
    typer.echo(f"metadata: {rec.metadata}")
    if rec.truth:
        faults = rec.truth.get("faults", [])
        typer.echo(f"truth: {sorted(rec.truth)}; {len(faults)} simulated fault(s)" + "".join(
            f"\n  motion {f['motion']}: {f['kind']} {f['t_start']:.3f}-{f['t_stop']:.3f} s"
            for f in faults))
    if rec.extra:
        typer.echo(f"other sidecar keys: {sorted(rec.extra)}")
    for p in rec.problems:
        typer.echo(f"problem [{p.kind}]: {p}")


def info(
    path: Path = typer.Argument(..., help="A recording (<name>.csv / .json / stem) or a folder."),
) -> None:
    """Summarise a recording (channels, events, metadata, problems) or a dataset folder
    (counts per label and session, problems found)."""
    from frictionfit.errors import FrictionfitError

    try:
        _dataset(path) if path.is_dir() else _recording(path)
    except FrictionfitError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
