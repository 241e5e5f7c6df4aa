"""``frictionfit plot``: a PNG of a recording, movement and relaxation phases shaded."""

from __future__ import annotations

from pathlib import Path

import typer

from frictionfit.cli._load import OVERWRITE_HELP, check_output, make_folder, reads_of

#: Figure formats ``--out`` may name.
FORMATS = (".png", ".pdf", ".svg")
#: Phase shading, in colours no channel line uses.
_SHADE = {"move_out": "gold", "move_back": "gold",
          "relax_out": "lightsteelblue", "relax_back": "lightsteelblue"}
#: Channel line colours (none of them a shading colour).
_LINES = ("tab:green", "tab:red", "tab:purple", "tab:brown", "black", "tab:pink", "tab:olive",
          "tab:cyan")


def plot(
    path: Path = typer.Argument(..., help="A recording: <name>.csv, <name>.json or the stem."),
    out: Path = typer.Option(None, help="PNG to write (default: <name>.png in the current "
                             "folder)."),
    no_events: bool = typer.Option(False, "--no-events",
                                   help="Find the phases from the force alone."),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Plot every channel against time, phases shaded (movement yellow, relaxation blue),
    missing samples (dropped rows, NaN) hatched red."""
    from frictionfit._optional import pyplot

    plt = pyplot("frictionfit plot")

    from frictionfit.errors import FrictionfitError, RecordingError
    from frictionfit.recording import read_recording, recording_paths
    from frictionfit.segmentation import segment

    out = out or Path(recording_paths(path)[0].stem + ".png")
    if out.suffix not in FORMATS:
        raise typer.BadParameter(f"{out}: write {', '.join(FORMATS)} (a figure)",
                                 param_hint="--out")
    make_folder(out.parent, "--out")
    check_output(out, "--out", FORMATS, overwrite=overwrite, reads=reads_of([path]))
    try:
        rec = read_recording(path, on_error="flag")
        for p in rec.disqualified:  # time stamps no grid can hold: nothing to shade
            if p.kind in ("too_short", "nonfinite_time", "nonmonotonic_time", "time_span"):
                raise RecordingError(str(p), path=recording_paths(path)[0])
        motions = segment(rec, drop_first=False, use_events=not no_events)
    except FrictionfitError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    fig, ax = plt.subplots(figsize=(12, 5), constrained_layout=True)
    for m in motions:
        for p in m.phases:
            ax.axvspan(m.t0 + p.start_s, m.t0 + p.stop_s, color=_SHADE[p.kind],
                       alpha=0.35 if p.kind.startswith("move") else 0.25, lw=0)
    for k, (start, stop) in enumerate(missing_spans(rec)):
        ax.axvspan(start, stop, facecolor="none", edgecolor="tab:red", hatch="////", lw=0.5,
                   label="missing samples" if k == 0 else None)
    for j, ch in enumerate(rec.channels):
        ax.plot(rec.t, rec.samples[:, j], lw=0.8, color=_LINES[j % len(_LINES)],
                label=f"{ch.name} [{ch.unit}]")
    for e in rec.events:
        ax.axvline(e.t, color="0.4", lw=0.5, ls=":")
    units = sorted({c.unit for c in rec.channels})
    ax.set(xlabel="t [s]", ylabel=f"signal [{', '.join(units)}]",
           title=f"{rec.name} ({rec.label}): movement yellow, relaxation blue, commands dotted")
    fig.legend(loc="outside lower center", fontsize=8, ncol=len(rec.channels) + 1)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    typer.echo(f"wrote {out} ({len(motions)} motion(s) shaded, {len(rec.problems)} problem(s))")


def missing_spans(rec) -> list[tuple[float, float]]:
    """Time spans (s) with a dropped row (a gap in ``t``) or a NaN in any channel."""
    import numpy as np

    if rec.n_samples < 2:
        return []
    nominal = 1.0 / rec.sample_rate_hz
    spans = [(float(a), float(b)) for a, b in zip(rec.t[:-1], rec.t[1:], strict=True)
             if b - a > 1.5 * nominal]
    bad = ~np.isfinite(rec.samples).all(axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, bad.astype(int), 0]))
    spans += [(float(rec.t[a]), float(rec.t[min(b, rec.n_samples - 1)]))
              for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return sorted(spans)
