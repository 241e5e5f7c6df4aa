"""``frictionfit fit``: fit the contact model to every motion and channel of recordings."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import typer

from frictionfit.cli._load import STRICT_HELP, check_writable


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
    strict: bool = typer.Option(False, help=STRICT_HELP),
    whole: bool = typer.Option(False, help="Fit each recording whole: one rig (motor timing), "
                               "sensor (offset, drift, leak) and contact law per recording and "
                               "channel, the law's state carried from stroke to stroke; "
                               "--model then names the law (no_peak2, relaxation, relaxation2, "
                               "rich, or auto: with or without a static peak by BIC)."),
    channel: list[str] = typer.Option([], help="With --whole: channels to fit (repeatable; "
                                      "default thumb_x and index_x)."),
) -> None:
    """Fit every non-preparatory motion x channel; one row per trial with status and stderr.

    Recordings at different sample rates are fitted on their own time grids; problems
    found on reading are printed and kept in the 'problems' column; a recording whose
    problems make its numbers wrong is skipped by name (--strict: stop)."""
    import pandas as pd

    from frictionfit.errors import FrictionfitError
    from frictionfit.fit import fit_report, fit_trials

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
    check_writable(out, "--out", (".csv", ".parquet"))
    files = [f for p in paths for f in (sorted(p.glob("*.csv")) if p.is_dir() else [p])]
    if whole:
        unsupported = [name for name, used_ in (("--uncertainty", uncertainty != "none"),
                       ("--plot", plot is not None), ("--tie", tie), ("--fix", fix),
                       ("--scheduler", scheduler), ("--n-starts", n_starts != 1),
                       ("--solver", solver != "lm")) if used_]
        if unsupported:
            raise typer.BadParameter(f"{', '.join(unsupported)} work on per-motion fits only",
                                     param_hint="--whole")
        law = model
        _fit_whole(files, strict, law, tuple(channel) or ("thumb_x", "index_x"), priors,
                   out, report)
        return
    batches, problems, used = _trials(files, strict)
    if not batches:
        typer.echo("error: no motion could be segmented from the given paths", err=True)
        raise typer.Exit(2)
    n_trials = sum(len(b.ids) for b in batches.values())
    typer.echo(f"fitting {n_trials} trials ({used} of {len(files)} recordings), "
               f"model={model} ...")
    options = dict(model=model, solver=solver, stroke_mm=stroke_mm, n_starts=n_starts, seed=seed,
                   fix=fixed, tie=tie, priors=priors)
    frames, wall, first = [], 0.0, None
    for batch in batches.values():  # one batch per sample interval: each on its own time grid
        y, drive_input = np.asarray(batch.ys), (np.asarray(batch.t_outs),
                                                np.asarray(batch.t_backs))
        try:
            if scheduler:
                from frictionfit.distributed import fit_distributed

                result = fit_distributed(y, batch.t, drive_input, scheduler=scheduler,
                                         groups=np.asarray(batch.groups), **options)
            else:
                result = fit_trials(y, batch.t, drive_input, groups=np.asarray(batch.groups),
                                    **options)
        except (FrictionfitError, ValueError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        frame = result.to_frame(batch.ids)
        if uncertainty != "none":
            frame = frame.merge(_posterior(result, y, batch.t, drive_input, uncertainty, chains,
                                           scheduler).to_frame(batch.ids), on="trial")
        frame.insert(1, "problems", [problems.get(i.split("/")[0], "") for i in batch.ids])
        frames.append(frame)
        wall += result.wall_s
        first = first or result
        if plot is not None:
            from frictionfit.fit import plot_fit

            plot.mkdir(parents=True, exist_ok=True)
            for i, trial_id in enumerate(batch.ids):
                plot_fit(result, i, batch.t, batch.ys[i],
                         plot / (trial_id.replace("/", "__") + ".png"), title=trial_id)
    _write(pd.concat(frames, ignore_index=True), out, "trials", wall)
    if report:
        typer.echo(fit_report(first, 0))


def _write(frame, out: Path, rows: str, wall_s: float) -> None:
    """Write the results table (.parquet or .csv) and say what it holds."""
    if out.suffix == ".parquet":
        frame.to_parquet(out)
    else:
        frame.to_csv(out, index=False)
    counts = frame["status"].value_counts().to_dict()
    typer.echo(f"{len(frame)} {rows} in {wall_s:.1f} s; status {counts}; wrote {out}")


def _usable(f: Path):
    """The recording at ``f``, its problems named on stderr; RecordingError where one of them
    makes its numbers wrong."""
    from frictionfit.errors import RecordingError
    from frictionfit.recording import read_recording

    rec = read_recording(f, on_error="flag")
    for p in rec.problems:
        typer.echo(f"{f}: [{p.kind}] {p}", err=True)
    if rec.disqualified:
        raise RecordingError(f"{rec.disqualified[0]}", path=f)
    return rec


def _fit_whole(files: list[Path], strict: bool, law: str, channels: tuple[str, ...],
               priors: dict | None, out: Path, report: bool) -> None:
    """``fit --whole``: one measurement fit per recording and channel, one row each."""
    from frictionfit.errors import FrictionfitError
    from frictionfit.fit import fit_report
    from frictionfit.fit.measurement import fit_measurements, measurement_data
    from frictionfit.models import MeasurementModel

    if priors and law == "auto":
        raise typer.BadParameter("priors need one law: choose --model", param_hint="--prior")
    try:
        model = law if law == "auto" else MeasurementModel(law).with_priors(priors)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--model / --prior") from None
    items, problems = [], []
    for f in files:
        try:
            rec = _usable(f)
            found = [measurement_data(rec, ch) for ch in channels]
        except (FrictionfitError, ValueError) as exc:
            if strict:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(2) from None
            typer.echo(f"skipped {exc}", err=True)  # one bad file never sinks the batch
            continue
        items += found
        problems += ["; ".join(f"[{p.kind}] {p}" for p in rec.problems)] * len(found)
    if not items:
        typer.echo("error: no recording could be fitted from the given paths", err=True)
        raise typer.Exit(2)
    typer.echo(f"fitting {len(items)} recording channels whole, law={law} ...")
    result = fit_measurements(items, model=model)
    frame = result.to_frame([f"{d.name}/{d.channel}" for d in items])
    frame.insert(1, "problems", problems)
    _write(frame, out, "recording channels", result.wall_s)
    if report:
        typer.echo(fit_report(result, 0))


@dataclass
class _Batch:
    """Trials of one sample interval: the time grid of its first motion, one row per trial."""

    t: np.ndarray
    ys: list = field(default_factory=list)
    t_outs: list = field(default_factory=list)
    t_backs: list = field(default_factory=list)
    ids: list = field(default_factory=list)
    groups: list = field(default_factory=list)


def _trials(files: list[Path], strict: bool) -> tuple[dict[float, _Batch], dict[str, str], int]:
    """Motions x channels of ``files``, batched by sample interval; each recording's problems
    (named on stderr); how many recordings were used. A recording that cannot be read or
    segmented, or whose problems make its numbers wrong, is skipped by name (``strict``:
    the command stops)."""
    from frictionfit.errors import FrictionfitError
    from frictionfit.segmentation import segment

    batches: dict[float, _Batch] = {}
    problems: dict[str, str] = {}
    used = 0
    for f in files:
        try:
            rec = _usable(f)
            motions = segment(rec)
        except FrictionfitError as exc:
            if strict:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(2) from None
            typer.echo(f"skipped {exc}", err=True)  # one bad file never sinks the batch
            continue
        used += 1
        problems[rec.name] = "; ".join(f"[{p.kind}] {p}" for p in rec.problems)
        for m in motions:
            batch = batches.setdefault(round(float(m.t[1] - m.t[0]), 12), _Batch(m.t))
            n = min(batch.t.size, m.t.size)
            for j, ch in enumerate(m.channels):
                y = np.full(batch.t.size, np.nan)
                y[:n] = m.samples[:n, j]
                batch.ys.append(y)
                batch.t_outs.append(m.t_out)
                batch.t_backs.append(m.t_back)
                batch.ids.append(f"{m.recording}/motion{m.index}/{ch.name}")
                batch.groups.append(f"{m.recording}/motion{m.index}")
    return batches, problems, used


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
