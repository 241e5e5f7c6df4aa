"""``frictionfit fit``: fit the contact model to every motion and channel of recordings."""

from __future__ import annotations

from pathlib import Path

import typer


def fit(
    paths: list[Path] = typer.Argument(..., help="Recordings (<name>.csv) or folders of them."),
    model: str = typer.Option("auto", help="auto, or one of elastic_plastic, stick_slip, "
                              "relaxation, rich."),
    solver: str = typer.Option("lm", help="lm (frictionfit's batched LM, fastest), optx-lm, "
                               "dogleg or gauss-newton (optimistix)."),
    out: Path = typer.Option(Path("fits.csv"), help="Results table: .csv or .parquet."),
    report: bool = typer.Option(False, help="Print the fit report of the first trial."),
    uncertainty: str = typer.Option("none", help="Posterior per trial: none, laplace, emcee "
                                    "or auto (Laplace; emcee where Laplace is doubtful)."),
    chains: Path = typer.Option(None, help="With emcee: save the chains to this HDF5 file."),
    plot: Path = typer.Option(None, help="Write a PNG of data vs. fit with residuals per "
                              "trial into this folder."),
    stroke_mm: float = typer.Option(1.0, help="The rig's finger stroke in mm (stiffness is "
                                    "per mm of it)."),
    n_starts: int = typer.Option(1, help="Starting points per trial (seeded multi-start)."),
    seed: int = typer.Option(0, help="Seed of the multi-start jitter."),
    fix: list[str] = typer.Option([], help="NAME=VALUE: hold a parameter at a physical value "
                                  "(repeatable), e.g. --fix tau=0.1."),
    prior: list[str] = typer.Option([], help="NAME=CENTRE,SD: a Normal prior (repeatable); for "
                                    "a log-scale parameter CENTRE is the median and SD that of "
                                    "its log, e.g. --prior ramp=0.15,0.3 (default ramp=0.125,0.3"
                                    "); NAME=none: flat over its bounds."),
    tie: list[str] = typer.Option([], help="NAME: share a parameter across the channels of "
                                  "each motion (repeatable)."),
    scheduler: str = typer.Option(None, help="Dask scheduler address (e.g. tcp://host:8786): "
                                  "partition the trials across its workers; results equal the "
                                  "local ones up to rounding."),
) -> None:
    """Fit every non-preparatory motion x channel; one row per trial with status and stderr."""
    import numpy as np

    from frictionfit.errors import FrictionfitError
    from frictionfit.fit import fit_report, fit_trials
    from frictionfit.recording import read_recording
    from frictionfit.segmentation import segment

    if uncertainty not in ("none", "laplace", "emcee", "auto"):
        raise typer.BadParameter(f"{uncertainty!r}: choose none, laplace, emcee or auto",
                                 param_hint="--uncertainty")
    if scheduler and chains is not None:
        raise typer.BadParameter("one HDF5 file cannot take writes from many Dask workers",
                                 param_hint="--chains with --scheduler")
    try:
        fixed = {k: float(v) for k, v in (item.split("=", 1) for item in fix)}
    except ValueError:
        raise typer.BadParameter(f"{fix}: write NAME=VALUE, e.g. tau=0.1",
                                 param_hint="--fix") from None
    priors = _priors(prior)
    files = [f for p in paths for f in (sorted(p.glob("*.csv")) if p.is_dir() else [p])]
    ys, t_outs, t_backs, ids, groups, t = [], [], [], [], [], None
    for f in files:
        try:
            motions = segment(read_recording(f, on_error="flag"))
        except FrictionfitError as exc:
            typer.echo(f"skipped: {exc}", err=True)  # one bad file never sinks the batch
            continue
        for m in motions:
            if t is None:
                t = m.t
            n = min(t.size, m.t.size)
            for j, ch in enumerate(m.channels):
                y = np.full(t.size, np.nan)
                y[:n] = m.samples[:n, j]
                ys.append(y)
                t_outs.append(m.t_out)
                t_backs.append(m.t_back)
                ids.append(f"{m.recording}/motion{m.index}/{ch.name}")
                groups.append(f"{m.recording}/motion{m.index}")
    if not ys:
        typer.echo("error: no motion could be segmented from the given paths", err=True)
        raise typer.Exit(2)
    typer.echo(f"fitting {len(ys)} trials ({len(files)} recordings), model={model} ...")
    y, drive_input = np.asarray(ys), (np.asarray(t_outs), np.asarray(t_backs))
    options = dict(model=model, solver=solver, stroke_mm=stroke_mm, n_starts=n_starts, seed=seed,
                   fix=fixed, tie=tie, groups=np.asarray(groups), priors=priors)
    try:
        if scheduler:
            from frictionfit.distributed import fit_distributed

            result = fit_distributed(y, t, drive_input, scheduler=scheduler, **options)
        else:
            result = fit_trials(y, t, drive_input, **options)
    except (FrictionfitError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    frame = result.to_frame(ids)
    if uncertainty != "none":
        frame = frame.merge(_posterior(result, y, t, drive_input, uncertainty, chains,
                                       scheduler).to_frame(ids), on="trial")
    if out.suffix == ".parquet":
        frame.to_parquet(out)
    else:
        frame.to_csv(out, index=False)
    if plot is not None:
        from frictionfit.fit import plot_fit

        plot.mkdir(parents=True, exist_ok=True)
        for i, trial_id in enumerate(ids):
            plot_fit(result, i, t, ys[i], plot / (trial_id.replace("/", "__") + ".png"))
    counts = frame["status"].value_counts().to_dict()
    typer.echo(f"{len(frame)} trials in {result.wall_s:.1f} s; status {counts}; wrote {out}")
    if report:
        typer.echo(fit_report(result, 0))


def _posterior(result, y, t, drive_input, method: str, chains: Path | None, scheduler: str | None):
    """``sample_posterior`` locally, or spread over the Dask cluster at ``scheduler``."""
    if scheduler:
        from frictionfit.distributed import posterior_distributed

        return posterior_distributed(result, y, t, drive_input, scheduler=scheduler,
                                     method=method)
    from frictionfit.uncertainty import sample_posterior

    return sample_posterior(result, y, t, drive_input, method=method, chains_path=chains)


def _priors(items: list[str]) -> dict | None:
    """``--prior`` values as ``fit_trials(priors=...)``: name -> (centre, sd) or None."""
    if not items:
        return None
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            out[name] = None if value.strip().lower() == "none" else tuple(
                float(v) for v in value.split(","))
            if out[name] is not None and len(out[name]) != 2:
                raise ValueError
        except ValueError:
            raise typer.BadParameter(f"{item!r}: write NAME=CENTRE,SD or NAME=none, e.g. "
                                     "ramp=0.15,0.3", param_hint="--prior") from None
    return out
