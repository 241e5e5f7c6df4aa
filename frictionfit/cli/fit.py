"""``frictionfit fit``: fit the contact model to recordings, whole or motion by motion."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer

from frictionfit.cli._load import (
    OVERWRITE_HELP,
    STRICT_HELP,
    WHOLE_LAWS_HELP,
    check_output,
    make_folder,
    problems_of,
    reads_of,
    stage,
    write_table,
)

#: Options that only per-motion fits (``--motions``) take.
_PER_MOTION = ("--chains", "--tie", "--scheduler", "--n-starts", "--solver")
_WHOLE_HELP = ("--whole (default): fit each rubbing measurement whole, one row per recording and "
               "channel: one rig (motor timing), sensor (offset, drift, leak) and contact law, "
               "the law's state carried from stroke to stroke. --motions: fit every "
               "non-preparatory motion x channel on its own, one row per trial (single strokes, "
               "multi-start, Dask).")
_RIG_HELP = ("Whole fits: recording (the motor's timing fitted for each recording and channel; a "
             "fit whose movement duration stands out of the others of its session and channel in "
             "the batch, five or more, is fitted again from their median profile, the better BIC "
             "kept), session (the movement's duration and acceleration held at the median of each "
             "session's fits, then fitted again: one motor profile all day, the spread of the "
             "session's profiles carried into the stderrs; the latency stays per recording) or a "
             ".json file of session profiles written by --save-rig (a recording fitted later in "
             "the day holds its day's profile).")
_CREEP_HELP = ("Whole fits: recording (the finger's creep, the slow relaxation branch's time "
               "constant tau2, free in every fit) or session (fitted free first, then held at the "
               "median of each session's fits of the channel in the batch, its spread carried "
               "into the stderrs; a recording alone in its session keeps its own).")
_PRIOR_HELP = ("NAME=CENTRE,SD: a Normal prior (repeatable); for a log-scale parameter CENTRE is "
               "the median and SD that of its log, e.g. --prior ramp=0.15,0.3 (default "
               "ramp=0.125,0.3 and slip_length=0.05,1.5); NAME=none: flat over its bounds.")
_UNCERTAINTY_HELP = ("Posterior per row: none, laplace (quantiles of the fit's Gaussian, "
                     "milliseconds a row), emcee (slow: about a second a motion, ~7 s a whole "
                     "fit's row; check uq_converged) or auto (Laplace; emcee where Laplace is "
                     "doubtful).")


def _check_uncertainty(uncertainty: str) -> None:
    """A BadParameter unless ``uncertainty`` is none or a posterior method; the samplers
    (emcee, scipy.stats: ~0.7 s) are imported only when one is asked for."""
    if uncertainty != "none":
        from frictionfit.uncertainty import METHODS

        if uncertainty not in METHODS:
            raise typer.BadParameter(f"{uncertainty!r}: choose none, {', '.join(METHODS[:-1])} "
                                     f"or {METHODS[-1]}",
                                     param_hint="--uncertainty")


def fit(
    paths: list[Path] = typer.Argument(..., help="Recordings (<name>.csv) or folders of them."),
    whole: bool = typer.Option(True, "--whole/--motions", help=_WHOLE_HELP),
    model: str = typer.Option("auto", help=f"Contact law. Whole: {WHOLE_LAWS_HELP} "
                              "--motions: auto, elastic_plastic, stick_slip, relaxation or rich."),
    rig: str = typer.Option("recording", help=_RIG_HELP),
    save_rig: Path = typer.Option(None, help="Whole fits with --rig session: write each "
                                  "session's motor profile to this .json file."),
    creep: str = typer.Option("recording", help=_CREEP_HELP),
    channel: list[str] = typer.Option([], help="Channels to fit (repeatable; whole fits: "
                                      "default thumb_x and index_x; --motions: every channel). "
                                      "A dead (constant) channel is skipped by name."),
    out: Path = typer.Option(Path("fits.csv"), help="Results table: .csv or .parquet."),
    report: bool = typer.Option(False, help="Print the fit report of the first row."),
    plot: Path = typer.Option(None, help="Write a PNG of data vs. fit with residuals per row "
                              "into this folder."),
    stroke_mm: float = typer.Option(1.0, help="The rig's finger stroke in mm for recordings "
                                    "that do not declare one (metadata.stroke_mm, which wins "
                                    "where given). With neither, stiffness is per stroke and "
                                    "its columns say N/stroke."),
    fix: list[str] = typer.Option([], help="NAME=VALUE: hold a parameter at a physical value "
                                  "(repeatable; with the auto model, in the laws that have it), "
                                  "e.g. --fix tau=0.1."),
    prior: list[str] = typer.Option([], help=_PRIOR_HELP),
    strict: bool = typer.Option(False, help=STRICT_HELP),
    uncertainty: str = typer.Option("none", help=_UNCERTAINTY_HELP),
    chains: Path = typer.Option(None, help="--motions with emcee: save the chains to this HDF5 "
                                "file."),
    solver: str = typer.Option("lm", help="--motions: lm (frictionfit's batched LM, fastest), "
                               "optx-lm, dogleg or gauss-newton (optimistix)."),
    n_starts: int = typer.Option(1, help="--motions: starting points per trial (seeded "
                                 "multi-start)."),
    seed: int = typer.Option(0, help="--motions: seed of the multi-start jitter."),
    tie: list[str] = typer.Option([], help="--motions: NAME: share a parameter across the "
                                  "channels of each motion (repeatable)."),
    scheduler: str = typer.Option(None, help="--motions: Dask scheduler address (e.g. "
                                  "tcp://host:8786): partition the trials across its workers; "
                                  "results equal the local ones up to rounding."),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Fit the contact model to recordings; one row per recording x channel (whole fits) or per
    motion x channel (--motions), each with its status, values, stderr and flags.

    Problems found on reading are printed and kept in the 'problems' column; a recording whose
    problems make its numbers wrong is skipped by name (--strict: stop). Per-motion fits of
    recordings at different sample rates run on their own time grids."""
    fixed = _fixes(fix)
    priors = _priors(prior)
    _check_outputs(paths, rig, overwrite, ((out, "--out", (".csv", ".parquet")),
                                           (chains, "--chains", (".h5", ".hdf5")),
                                           (save_rig, "--save-rig", (".json",))))
    if plot is not None:
        make_folder(plot, "--plot")
    files = _files(paths)
    _check_uncertainty(uncertainty)
    given = dict(zip(_PER_MOTION, (chains is not None, tie, scheduler, n_starts != 1,
                                   solver != "lm"), strict=True))
    if whole:
        used = [name for name, value in given.items() if value]
        if used:
            raise typer.BadParameter(f"{', '.join(used)} work on per-motion fits only: add "
                                     "--motions", param_hint="--whole")
        _fit_whole(files, strict, model, tuple(channel) or ("thumb_x", "index_x"), fixed,
                   priors, stroke_mm, (_rig_option(rig, save_rig), creep), uncertainty,
                   _Output(out, plot, report, save_rig, overwrite))
        return
    if rig != "recording" or save_rig is not None:
        raise typer.BadParameter("per-motion fits fit the motor per motion",
                                 param_hint="--rig / --save-rig")
    if scheduler and chains is not None:
        raise typer.BadParameter("one HDF5 file cannot take writes from many Dask workers",
                                 param_hint="--chains with --scheduler")
    options = dict(model=model, solver=solver, stroke_mm=stroke_mm, n_starts=n_starts, seed=seed,
                   fix=fixed, tie=tie, priors=priors)
    _fit_motions(files, strict, tuple(channel), options,
                 _Posterior(uncertainty, chains, scheduler),
                 _Output(out, plot, report, overwrite=overwrite))


@dataclass(frozen=True)
class _Output:
    """Where the results go: the table, the PNG folder (or None), whether to print a report."""

    table: Path
    plots: Path | None
    report: bool
    rigs: Path | None = None  # whole fits: the sessions' motor profiles (.json)
    overwrite: bool = False  # replace existing PNGs in ``plots``

    def check_plots(self, ids: Sequence[str]) -> None:
        """Refuse, before fitting, PNGs of ``ids`` that exist in ``plots`` (without
        ``overwrite``)."""
        if self.plots is not None:
            for name in ids:
                check_output(_plot_path(self.plots, name), "--plot", overwrite=self.overwrite)


def _check_outputs(paths: list[Path], rig: str, overwrite: bool, outputs: tuple) -> None:
    """Each ``(path, option, suffixes)`` of ``outputs`` checked before any work
    (:func:`~frictionfit.cli._load.check_output`) against what the command reads: the
    recordings of ``paths`` and a ``--rig`` file."""
    reads = reads_of(paths) + ([Path(rig)] if rig.endswith(".json") else [])
    for path, option, suffixes in outputs:
        check_output(path, option, suffixes, overwrite=overwrite, reads=reads)


def _plot_path(folder: Path, name: str) -> Path:
    """The data-vs-fit PNG of row ``name`` in ``folder``."""
    return folder / (name.replace("/", "__") + ".png")


def _files(paths: list[Path]) -> list[Path]:
    """The recordings of ``paths`` (a folder: its ``*.csv``, sorted); an empty folder is
    refused in words."""
    files = []
    for p in paths:
        found = sorted(p.glob("*.csv")) if p.is_dir() else [p]
        if p.is_dir() and not found:
            raise typer.BadParameter(f"{p}: the folder is empty of recordings (no <name>.csv)",
                                     param_hint="PATHS")
        files += found
    return files


@dataclass(frozen=True)
class _Posterior:
    """The posterior asked of per-motion fits: method, chains file, Dask scheduler."""

    method: str
    chains: Path | None
    scheduler: str | None


def _fit_motions(files: list[Path], strict: bool, channels: tuple[str, ...], options: dict,
                 posterior: _Posterior, output: _Output) -> None:
    """``fit --motions``: every non-preparatory motion x channel (``channels``, default
    every one), one batch per sample rate."""
    import pandas as pd

    from frictionfit.errors import FrictionfitError
    from frictionfit.fit import fit_report, fit_trials

    batches, problems, used = _trials(files, strict, channels)
    if not batches:
        typer.echo("error: no motion could be segmented from the given paths", err=True)
        raise typer.Exit(2)
    output.check_plots([i for b in batches for i in b.ids])
    n_trials = sum(b.n_trials for b in batches)
    typer.echo(f"fitting {n_trials} trials ({used} of {len(files)} recordings), "
               f"model={options['model']} ...")
    frames, wall, first = [], 0.0, None
    for trials in batches:  # one batch per sample interval: each on its own time grid
        groups = np.asarray(trials.groups)
        try:
            if posterior.scheduler:
                from frictionfit.distributed import fit_distributed

                result = fit_distributed(trials, scheduler=posterior.scheduler, groups=groups,
                                         **options)
            else:
                with stage(f"fitting {_count(trials.n_trials, 'trial')}"):
                    result = fit_trials(trials, groups=groups, **options)
        except (FrictionfitError, ValueError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        frame = result.to_frame(trials.ids)
        if posterior.method != "none":
            with stage(f"posteriors ({posterior.method}) of {_count(trials.n_trials, 'trial')}"):
                post = _posterior(result, trials, posterior)
            typer.echo(f"posteriors ({posterior.method}) in {post.wall_s:.1f} s: "
                       f"{post.verdict()}")
            frame = frame.merge(post.to_frame(trials.ids), on="trial")
        frame.insert(1, "problems", [problems.get(i.split("/")[0], "") for i in trials.ids])
        frames.append(frame)
        wall += result.wall_s
        first = first or result
        _plots(result, [(trials.t, y_i) for y_i in trials.y], list(trials.ids), output.plots)
    _write(pd.concat(frames, ignore_index=True), output.table, "trial", wall)
    if output.report:
        typer.echo(fit_report(first, 0))


def _plots(result, curves: list[tuple], ids: list[str], folder: Path | None) -> None:
    """One data-vs-fit PNG per row of ``result`` (``curves``: its ``(t, y)``) in ``folder``."""
    if folder is None:
        return
    from frictionfit.fit import plot_fit

    folder.mkdir(parents=True, exist_ok=True)
    for i, ((t, y), name) in enumerate(zip(curves, ids, strict=True)):
        plot_fit(result, i, t, y, _plot_path(folder, name), title=name)


def _count(n: int, noun: str) -> str:
    """``n noun``, the noun plural unless ``n`` is 1."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _write(frame, out: Path, rows: str, wall_s: float) -> None:
    """Write the results table (.parquet or .csv) and say what it holds (``rows``: what a
    row is, singular)."""
    write_table(frame, out)
    counts = frame["status"].value_counts().to_dict()
    models = frame["model"].value_counts().to_dict()
    typer.echo(f"{_count(len(frame), rows)} in {wall_s:.1f} s; status {counts}; models {models}; "
               f"wrote {out}")


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


def _prepared(files: list[Path], strict: bool, prepare):
    """``(recording, prepare(recording))`` of each usable file, in order. A file that cannot
    be read or prepared, or whose problems make its numbers wrong, is skipped by name (one bad
    file never sinks the batch; ``strict``: the command stops)."""
    from frictionfit.errors import FrictionfitError

    for f in files:
        try:
            rec = _usable(f)
            prepared = prepare(rec)
        except (FrictionfitError, ValueError) as exc:
            if strict:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(2) from None
            typer.echo(f"skipped {exc}", err=True)
            continue
        yield rec, prepared


def _rig_option(rig: str, save_rig: Path | None) -> str | dict:
    """``--rig`` as ``fit_recordings`` takes it: a name, or the session profiles read from a
    .json file; ``--save-rig`` checked (it needs ``--rig session``)."""
    if save_rig is not None:
        if rig != "session":
            raise typer.BadParameter("the profiles are estimated with --rig session",
                                     param_hint="--save-rig")
    if rig in ("recording", "session"):
        return rig
    if not rig.endswith(".json"):
        raise typer.BadParameter(f"{rig!r}: choose recording or session, or a .json file of "
                                 "session profiles (written by --save-rig)", param_hint="--rig")
    from frictionfit.fit.session import read_session_rigs

    try:
        return read_session_rigs(rig)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--rig") from None


def _fit_whole(files: list[Path], strict: bool, law: str, channels: tuple[str, ...],
               fixed: dict, priors: dict | None, stroke_mm: float,
               rig_creep: tuple[str | dict, str], uncertainty: str, output: _Output) -> None:
    """``fit --whole``: one measurement fit per recording and channel, one row each (with
    its posterior's quantiles unless ``uncertainty`` is "none"); ``rig_creep``: the motor's
    and the creep's level (``--rig``, ``--creep``)."""
    from frictionfit.fit import measurement_data
    from frictionfit.models import MeasurementModel
    from frictionfit.whole_fit import fit_recordings

    if law == "auto" and (priors or stroke_mm != 1.0):
        raise typer.BadParameter("priors and a stroke need one law: choose --model",
                                 param_hint="--prior / --stroke-mm")
    try:
        model = (law if law == "auto"
                 else MeasurementModel(law, stroke_mm=stroke_mm).with_priors(priors))
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--model / --prior") from None

    def fitted_channels(rec):
        """The channels of ``rec`` that can be fitted (:func:`_each_channel`)."""
        if not any(e.kind == "move" for e in rec.events):
            raise ValueError(f"{rec.name}: no 'move' events: a whole fit needs the motor's "
                             "commands; fit the motions found in the force with --motions")
        return _each_channel(rec, channels, strict,
                             lambda ch: measurement_data(rec, ch, stroke_mm=stroke_mm))

    items, problems = [], []
    for rec, found in _prepared(files, strict, fitted_channels):
        items += found
        problems += [problems_of(rec)] * len(found)
    if not items:
        typer.echo("error: no recording could be fitted from the given paths", err=True)
        raise typer.Exit(2)
    output.check_plots([f"{d.name}/{d.channel}" for d in items])
    typer.echo(f"fitting {_count(len(items), 'recording channel')} whole, law={law} ...")
    try:
        with stage(f"fitting {_count(len(items), 'recording channel')}"):
            result = fit_recordings(items, model=model, fix=fixed, rig=rig_creep[0],
                                    creep=rig_creep[1])
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--fix / --rig / --creep") from None
    if output.rigs is not None:
        from frictionfit.fit.session import write_session_rigs

        write_session_rigs(result.session_rigs, output.rigs)
        typer.echo(f"{len(result.session_rigs)} session motor profile(s) -> {output.rigs}")
    ids = result.ids
    frame = result.to_frame(ids)
    frame.insert(1, "problems", problems)
    # where each movement's onset and duration came from: the motor's reads or the force
    frame.insert(2, "timing", ["motor" if d.motor is not None else "force" for d in items])
    if uncertainty != "none":
        with stage(f"posteriors ({uncertainty}) of {_count(len(items), 'row')}"
                   + (", ~7 s a row" if uncertainty != "laplace" else "")):
            post = result.posterior(method=uncertainty)
        frame = frame.merge(post.to_frame(ids), on="trial")
        typer.echo(f"posteriors ({uncertainty}) in {post.wall_s:.1f} s: {post.verdict()}")
    _write(frame, output.table, "recording channel", result.wall_s)
    if output.plots is not None:
        with stage(f"plotting {_count(len(ids), 'row')} into {output.plots}"):
            _plots(result, [(d.t[d.mask], d.y[d.mask]) for d in items], ids, output.plots)
    if output.report:
        typer.echo(result.report(0))


def _each_channel(rec, names: Sequence[str], strict: bool, take: Callable[[str], Any]
                  ) -> list:
    """``take(name)`` of each of ``names`` of ``rec``; a channel it refuses (a ValueError
    naming it) is skipped by name on stderr, so one dead sensor does not cost the others
    (``strict``, or the only channel asked: the refusal stops the recording). ValueError
    when none is left."""
    found = []
    for name in names:
        try:
            found.append(take(name))
        except ValueError as exc:
            if strict or len(names) == 1:
                raise
            typer.echo(f"skipped {exc}", err=True)
    if not found:
        raise ValueError(f"{rec.name}: none of the channels {', '.join(names)} can be fitted")
    return found


def _trials(files: list[Path], strict: bool, channels: tuple[str, ...] = ()):
    """Motions x ``channels`` (default every channel) of ``files`` as
    :class:`~frictionfit.fit.Trials`, one batch per sample interval; each recording's
    problems (named on stderr); how many recordings were used. A recording that cannot be
    read or segmented, or whose problems make its numbers wrong, is skipped by name, and so
    is a dead channel (``strict``: the command stops)."""
    from dataclasses import replace

    from frictionfit.fit import Trials
    from frictionfit.recording import check_newtons
    from frictionfit.segmentation import segment

    def motions_in_newtons(rec):
        names = list(channels) or list(rec.channel_names)
        for name in names:
            rec.channel(name)  # a RecordingError naming a channel the recording lacks
        dead = {p.channel: p.detail for p in rec.problems if p.kind == "dead_channel"}

        def alive(name: str) -> str:
            if name in dead:
                raise ValueError(f"{rec.name}: channel {name!r}: {dead[name]}")
            return name

        keep = _each_channel(rec, names, strict, alive)
        check_newtons(rec.name, rec.channels, keep)
        cols = [rec.channel_names.index(n) for n in keep]
        return [replace(m, channels=tuple(m.channels[j] for j in cols), samples=m.samples[:, cols])
                for m in segment(rec)]

    by_interval: dict[float, list] = {}
    problems: dict[str, str] = {}
    used = 0
    for rec, motions in _prepared(files, strict, motions_in_newtons):
        used += 1
        problems[rec.name] = problems_of(rec)
        for m in motions:
            by_interval.setdefault(round(float(m.t[1] - m.t[0]), 12), []).append(m)
    return [Trials.from_motions(ms) for ms in by_interval.values()], problems, used


def _posterior(result, trials, posterior: _Posterior):
    """``sample_posterior`` of the fitted ``trials`` locally, or spread over the Dask cluster
    at its scheduler."""
    if posterior.scheduler:
        from frictionfit.distributed import posterior_distributed

        return posterior_distributed(result, trials, scheduler=posterior.scheduler,
                                     method=posterior.method)
    from frictionfit.uncertainty import sample_posterior

    return sample_posterior(result, trials, method=posterior.method,
                            chains_path=posterior.chains)


def _fixes(items: list[str]) -> dict[str, float]:
    """``--fix`` values: name -> physical value."""
    try:
        return {k: float(v) for k, v in (item.split("=", 1) for item in items)}
    except ValueError:
        raise typer.BadParameter(f"{items}: write NAME=VALUE, e.g. tau=0.1",
                                 param_hint="--fix") from None


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
