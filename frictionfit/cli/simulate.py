"""``frictionfit simulate``: rubbing measurements (default) or touch gestures with known truth."""

from __future__ import annotations

from pathlib import Path

import typer

from frictionfit.cli._load import make_folder

app = typer.Typer(help="Simulate rubbing measurements or touch gestures with known truth.")


def _folder(out: Path, overwrite: bool, pattern: str = "*.json") -> None:
    """Make ``out``, before any work; refuse a folder that holds recordings which are not
    simulated (their names could be the simulator's: a lab's data is never overwritten), and
    one holding simulated files (``pattern``) unless ``overwrite``."""
    import json

    make_folder(out, "--out")
    for side in sorted(out.glob("*.json")):
        try:
            synthetic = json.loads(side.read_text()).get("metadata", {}).get("synthetic")
        except (OSError, ValueError, AttributeError):
            synthetic = None
        if synthetic is not True:
            raise typer.BadParameter(f"{out} holds recordings that are not simulated (e.g. "
                                     f"{side.name}); choose another folder", param_hint="--out")
    made = sorted(out.glob(pattern))
    if made and not overwrite:
        raise typer.BadParameter(f"{out} holds {len(made)} simulated file(s) (e.g. "
                                 f"{made[0].name}): add --overwrite to replace those written "
                                 "again, or choose another folder", param_hint="--out")


@app.callback(invoke_without_command=True)
def simulate(
    ctx: typer.Context,
    out: Path = typer.Option(None, help="Folder to write the measurements to (required)."),
    seed: int = typer.Option(0, help="Master seed: the same seed gives the same files."),
    sessions: int = typer.Option(2, min=1, help="Recording sessions (days), numbered from 1."),
    measurements_per_class: int = typer.Option(2, min=1, help="Measurements per class and "
                                               "session."),
    classes: str = typer.Option("", help="Comma-separated class labels (default: all 35), "
                                "e.g. 'paper-1,paper-2'."),
    motor_positions: float = typer.Option(
        0.0, min=0.0, help="Also read the motor's position this often (Hz), as `frictionfit "
        "rub --position-rate` does; 0: no reads, as in the lab's recordings. The whole fits "
        "then take each movement's timing from the reads."),
    rig: str = typer.Option("default", help="The simulated rig: default (no rig effect), "
                            "sim-a, sim-b or sim-c (strokes, motor speeds, fingers' compliance, "
                            "play and creep, sensors, sample rates of three lab-like rigs; "
                            "frictionfit.simulation.rigs)."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    overwrite: bool = typer.Option(False, help="Replace the simulated recordings of an earlier "
                                   "run in --out (recordings not simulated are never "
                                   "replaced)."),
) -> None:
    """Write simulated rubbing measurements (35 classes x sessions x measurements-per-class)."""
    if ctx.invoked_subcommand is not None:
        return
    if out is None:
        typer.echo("error: --out DIR is required", err=True)
        raise typer.Exit(2)
    from rich.progress import Progress

    from frictionfit.simulation.materials import CLASSES
    from frictionfit.simulation.measurements import simulate_dataset
    from frictionfit.simulation.rigs import RIGS

    if rig not in RIGS:
        raise typer.BadParameter(f"unknown rig {rig!r}; choose from {', '.join(RIGS)}",
                                 param_hint="--rig")
    labels = [c.strip() for c in classes.split(",") if c.strip()] or list(CLASSES)
    unknown = [c for c in labels if c not in CLASSES]
    if unknown:
        typer.echo(f"error: unknown class(es) {unknown}; known: {', '.join(CLASSES)}", err=True)
        raise typer.Exit(2)
    _folder(out, overwrite)
    total = sessions * len(labels) * measurements_per_class
    with Progress(disable=not progress, transient=True) as bar:
        task = bar.add_task("simulating measurements", total=total)
        paths = simulate_dataset(out, seed, sessions, measurements_per_class, labels,
                                 position_rate_hz=motor_positions, rig=RIGS[rig],
                                 progress=lambda n: bar.advance(task, n))
    typer.echo(f"wrote {len(paths)} measurements ({len(labels)} classes, {sessions} session(s)"
               + (f", rig {rig}" if rig != "default" else "") + f") to {out}")


@app.command("gestures", short_help="Simulated touch gestures on a textile skin.")
def gestures(
    out: Path = typer.Option(..., help="Folder to write the SYNTHETIC gesture .npz files to."),
    seed: int = typer.Option(0, help="Master seed."),
    people: int = typer.Option(5, min=1, help="Number of people."),
    repetitions: int = typer.Option(16, min=1, help="Repetitions of each gesture per person."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    overwrite: bool = typer.Option(False, help="Replace the gesture files of an earlier run in "
                                   "--out."),
) -> None:
    """Write simulated touch gestures: people x 7 gestures x repetitions."""
    from frictionfit.simulation.gestures import simulate_gestures

    _folder(out, overwrite, "*.npz")
    paths = simulate_gestures(out, seed, people, repetitions, progress=progress)
    typer.echo(f"wrote {len(paths)} synthetic gestures to {out}")
