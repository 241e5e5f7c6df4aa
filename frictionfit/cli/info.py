"""``frictionfit info``: summarise a recording or a folder of recordings."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from frictionfit.cli._load import STRICT_HELP, problems_of


def _dataset(spec: str, strict: bool) -> None:
    from collections import Counter

    from frictionfit.cli._load import load_recordings

    recs = load_recordings(spec if not Path(spec).is_dir() else f"recordings:{spec}", strict)
    labels = Counter(str(r.label) for r in recs)
    sessions = sorted({r.metadata.get("session") for r in recs}, key=str)
    if sessions == [None]:  # a dataset without sessions (FabricSlide, gestures): one column
        sessions = []
    problems = Counter(p.kind for r in recs for p in r.problems)
    flagged = [r for r in recs if r.problems]
    typer.echo(f"{spec}: {len(recs)} recordings, {len(labels)} labels, "
               f"{len(sessions) or 'no'} session(s), {len(flagged)} with problems")
    typer.echo(f"channels: {', '.join(f'{c.name} [{c.unit}]' for c in recs[0].channels)}")
    per = Counter((str(r.label), r.metadata.get("session")) for r in recs)
    width = max(len(label) for label in labels)
    typer.echo(f"{'label':{width}s}  " + "".join(f"s{s}  " for s in sessions) + "total")
    for label in sorted(labels):
        cells = "".join(f"{per[(label, s)]:>{len(f's{s}')}d}  " for s in sessions)
        typer.echo(f"{label:{width}s}  {cells}{labels[label]:5d}")
    if problems:
        typer.echo("problems: " + ", ".join(f"{k} x{n}" for k, n in sorted(problems.items())))
        for r in flagged:
            typer.echo(f"  {r.name}: {problems_of(r)}")


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
        faults = faults if isinstance(faults, list) else []
        typer.echo(f"truth: {sorted(rec.truth)}; {len(faults)} simulated fault(s)" + "".join(
            f"\n  {_fault(f)}" for f in faults))
    acq = rec.extra.get("acquisition")
    if isinstance(acq, dict) and acq.get("status") == "recording":
        typer.echo(f"acquisition: interrupted (status 'recording'): {rec.n_samples} rows in the "
                   f"CSV, the sidecar last counted {acq.get('rows', '?')}")
    elif isinstance(acq, dict) and acq.get("status") == "failed":
        typer.echo(f"acquisition: failed ({acq.get('failure', 'no reason kept')}): "
                   f"{rec.n_samples} rows in the CSV")
    if isinstance(acq, dict):
        typer.echo(_acquisition(acq))
    if rec.extra:
        typer.echo(f"other sidecar keys: {sorted(rec.extra)}")
    for p in rec.problems:
        typer.echo(f"problem [{p.kind}]: {p}")
    if rec.disqualified:
        typer.echo(f"error: {path}: unusable, every command skips it: "
                   + "; ".join(f"[{p.kind}] {p}" for p in rec.disqualified), err=True)
        raise typer.Exit(1)


#: Breaks of the acquisition ``info`` lists one by one; the rest are counted.
SHOWN_BREAKS = 5


def _acquisition(acq: dict) -> str:
    """What the sidecar's ``acquisition`` object says of the recording, in a few lines:
    samples lost and corrupted frames, reconnections, overloaded frames, and its first
    listed breaks (gaps, restarts) with their causes."""
    def dicts(key: str) -> list[dict]:
        found = acq.get(key)
        return [d for d in found if isinstance(d, dict)] if isinstance(found, list) else []

    def number(value) -> int:  # a hand-edited sidecar may hold anything
        return int(value) if isinstance(value, (int, float)) and math.isfinite(value) else 0

    sensors, gaps = dicts("sensors"), dicts("gaps")

    def total(key: str) -> int:
        return sum(number(s.get(key)) for s in sensors) if sensors else number(acq.get(key))

    unlisted = total("gaps_unlisted")
    lines = [f"acquisition: {acq.get('rows', '?')} rows at {acq.get('rate_hz_achieved', '?')} Hz "
             f"achieved; {total('samples_lost')} sample(s) lost, {total('frames_corrupted')} "
             f"corrupted frame(s) dropped, {total('reconnects')} reconnection(s), "
             f"{total('frames_overloaded')} frame(s) flagged overloaded"]
    for g in gaps[:SHOWN_BREAKS]:
        sensor = f"{g['sensor']}: " if "sensor" in g else ""
        lines.append(f"  break at t={g.get('t', '?')} s, {sensor}{g.get('samples', '?')} "
                     f"sample(s): {g.get('cause', '?')}")
    if len(gaps) > SHOWN_BREAKS:
        lines.append(f"  ... and {len(gaps) - SHOWN_BREAKS} more in the sidecar's "
                     "acquisition.gaps")
    if unlisted:
        lines.append(f"  ... and {unlisted} more counted, not listed")
    return "\n".join(lines)


def _fault(f) -> str:
    """One simulated fault of ``truth["faults"]``, whatever keys it has."""
    if not isinstance(f, dict):
        return f"fault {f!r}"
    span = (f"{f['t_start']:.3f}-{f['t_stop']:.3f} s"
            if isinstance(f.get("t_start"), (int, float))
            and isinstance(f.get("t_stop"), (int, float)) else "(no time span)")
    return f"motion {f.get('motion', '?')}: {f.get('kind', '?')} {span}"


def info(
    path: str = typer.Argument(..., help="A recording (<name>.csv / .json / stem), a folder of "
                               "them, or KIND:PATH (e.g. fabricslide:DIR)."),
    strict: bool = typer.Option(False, help=STRICT_HELP),
) -> None:
    """Summarise a recording (channels, events, metadata, problems) or a dataset
    (counts per label and session, problems found, recordings skipped)."""
    from frictionfit.errors import FrictionfitError

    try:
        kind, sep, _ = path.partition(":")
        if Path(path).is_dir() or (sep and kind.isalpha() and len(kind) > 1):
            _dataset(path, strict)
        else:
            _recording(Path(path))
    except FrictionfitError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
