"""``frictionfit plot``: a PNG of a recording, movement and relaxation phases shaded."""

from __future__ import annotations

from pathlib import Path

import typer

_SHADE = {"move_out": "tab:orange", "move_back": "tab:orange",
          "relax_out": "tab:blue", "relax_back": "tab:blue"}


def plot(
    path: Path = typer.Argument(..., help="A recording: <name>.csv, <name>.json or the stem."),
    out: Path = typer.Option(None, help="PNG to write (default: <name>.png beside the data)."),
    no_events: bool = typer.Option(False, "--no-events",
                                   help="Find the phases from the force alone."),
) -> None:
    """Plot every channel against time, phases shaded (movement orange, relaxation blue)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from frictionfit.errors import FrictionfitError
    from frictionfit.recording import read_recording
    from frictionfit.segmentation import segment

    try:
        rec = read_recording(path, on_error="flag")
        motions = segment(rec, drop_first=False, use_events=not no_events)
    except FrictionfitError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    out = out or Path(path).with_suffix("").with_suffix(".png")
    fig, ax = plt.subplots(figsize=(12, 4.5), constrained_layout=True)
    for m in motions:
        for p in m.phases:
            ax.axvspan(m.t0 + p.start_s, m.t0 + p.stop_s, color=_SHADE[p.kind],
                       alpha=0.25 if p.kind.startswith("move") else 0.08, lw=0)
    for j, ch in enumerate(rec.channels):
        ax.plot(rec.t, rec.samples[:, j], lw=0.8, label=f"{ch.name} [{ch.unit}]")
    for e in rec.events:
        ax.axvline(e.t, color="0.4", lw=0.5, ls=":")
    units = sorted({c.unit for c in rec.channels})
    ax.set(xlabel="t [s]", ylabel=f"signal [{', '.join(units)}]",
           title=f"{rec.name} ({rec.label}): movement orange, relaxation blue, commands dotted")
    ax.legend(loc="upper right", fontsize=8, ncol=len(rec.channels))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    typer.echo(f"wrote {out} ({len(motions)} motions shaded, {len(rec.problems)} problem(s))")
