"""``frictionfit demo``: simulate a measurement with known truth, read it back, fit it."""

from __future__ import annotations

from pathlib import Path

import typer


def demo(
    out: Path = typer.Option(Path("frictionfit-demo"), help="Folder for the demo's files."),
    seed: int = typer.Option(0, help="Seed of the simulation."),
) -> None:
    """Write a 4-motion simulated measurement, fit the relaxation model, compare with truth."""
    import numpy as np

    from frictionfit.fit import fit_report, fit_trials
    from frictionfit.recording import Event, Recording, read_recording, write_recording
    from frictionfit.segmentation import segment
    from frictionfit.simulation.trials import simulate_trials

    ts = simulate_trials("relaxation", 5, seed=seed, snr_db=25.0)
    index_x = (ts.direction[:, None] * (ts.y - ts.truth["offset"][:, None])).ravel()
    samples = np.stack([index_x + 0.3, -0.8 * index_x - 0.2], axis=1)
    events = [Event(ts.t_out + 2 * k + dt, "move", tgt)
              for k in range(5) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    truth = {n: v.tolist() for n, v in ts.truth.items()}
    rec = Recording.from_arrays(samples, 1000.0, ["index_x", "thumb_x"], events=events,
                                metadata={"label": "demo-1", "session": 1, "trial": 1},
                                truth=truth, name="demo")
    path = write_recording(rec, out / "demo")
    rec = read_recording(path)
    motions = segment(rec)
    typer.echo(f"wrote {path}: {rec.n_samples} samples, {len(motions)} motions after the "
               "preparatory one")
    y = np.stack([m.samples[:, 0] for m in motions])
    result = fit_trials(y, motions[0].t, (motions[0].t_out, motions[0].t_back),
                        model="relaxation")
    result.to_frame([f"motion{m.index}" for m in motions]).to_csv(out / "fits.csv", index=False)
    typer.echo(fit_report(result, 0))
    typer.echo("\nparameter        truth(motion1)   fitted")
    for name in ("f_kin", "f_static_excess", "relax_frac", "tau"):
        typer.echo(f"{name:16s} {ts.truth[name][1]:12.4g}   {result.values[0][name]:.4g}")
    typer.echo(f"\nall fits: {out / 'fits.csv'}")
