"""``frictionfit bench``: speed against error on seeded simulated trials, one report."""

from __future__ import annotations

from pathlib import Path

import typer

from frictionfit.cli._load import OVERWRITE_HELP, check_output, make_folder, reads_of

STAGES = ("fit", "uncertainty", "classify")


def _run_stage(name: str, quick: bool, seed: int, *args) -> dict:
    """``frictionfit.bench.<name>.run``; a missing or failing stage is reported, not raised."""
    import importlib

    try:
        module = importlib.import_module(f"frictionfit.bench.{name}")
        return module.run(*args, quick=quick, seed=seed)
    except Exception as exc:  # noqa: BLE001 - one failing stage never sinks the report
        return {"stage": name, "error": f"{type(exc).__name__}: {exc}", "summary": {}}


def bench(
    what: str = typer.Argument("all", help="fit, uncertainty, classify, hard-cases, scaling, "
                               "all (every stage + scaling + Dask speed-up + hard cases), or "
                               "lab (whole fits of the --dataset folder, scored without a "
                               "truth: convergence, spread over motions, agreement between "
                               "sessions, ranks against measured quantities)."),
    out: Path = typer.Option(..., help="Folder for bench.json, bench.md, speed_vs_error.png."),
    quick: bool = typer.Option(False, help="Small configurations (minutes, not an hour)."),
    seed: int = typer.Option(0, help="Seed of the simulated trials."),
    scheduler: str = typer.Option(None, help="Dask scheduler address for the distributed "
                                  "timing (default: a local 2-worker cluster)."),
    results: Path = typer.Option(None, help="Also add the table, dated, to this results file "
                                 "(e.g. docs/results.md)."),
    dataset: Path = typer.Option(None, help="lab: a folder of rubbing recordings, e.g. "
                                 "../shared/datasets/rubbing-lab (--quick: every 20th)."),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Run the benchmark on simulated trials with known truth (or, lab, on recordings without
    one); write the JSON, table and plot."""
    choices = (*STAGES, "hard-cases", "scaling", "all", "lab")
    if what not in choices:
        typer.echo(f"error: unknown benchmark {what!r}; choose from {', '.join(choices)}",
                   err=True)
        raise typer.Exit(2)
    if (what == "lab") != (dataset is not None):
        raise typer.BadParameter("lab needs a folder of recordings, and only lab takes one",
                                 param_hint="--dataset")
    make_folder(out, "--out")
    reads = reads_of([dataset]) if dataset is not None else []
    for name in ("bench.json", "bench.md", "speed_vs_error.png"):
        check_output(out / name, "--out", overwrite=overwrite, reads=reads)
    check_output(results, "--results", reads=reads, replaces=False)
    from frictionfit.bench.report import merge, record_results, write_report

    stages = [_run_stage(s, quick, seed) for s in STAGES if what in (s, "all")]
    if what == "lab":
        stages.append(_run_stage("lab", quick, seed, dataset))
    parts = {}
    if what in ("scaling", "all"):
        from frictionfit.bench import scaling

        parts["scaling"] = scaling.run(quick=quick, seed=seed)
        if what == "all":
            from frictionfit._optional import MissingExtraError

            try:
                parts["dask"] = scaling.dask_speedup(64 if quick else 256, 2 if quick else 3,
                                                     seed, scheduler)
            except MissingExtraError as exc:
                typer.echo(f"skipped the Dask speed-up: {exc}", err=True)
    if what in ("hard-cases", "all"):
        from frictionfit.bench import hard_cases

        parts["hard_cases"] = hard_cases.run(quick=quick, seed=seed)
    command = (f"frictionfit bench {what} --out {out}" + (" --quick" if quick else "")
               + (f" --seed {seed}" if seed else "")
               + (f" --scheduler {scheduler}" if scheduler else "")
               + (f" --dataset {dataset}" if dataset else ""))
    paths = write_report(merge(stages, command=command, **parts), out)
    if results is not None:
        record_results(results, command, paths["markdown"].read_text())
        typer.echo(f"added the table to {results}")
    for stage in stages:
        if "error" in stage:
            typer.echo(f"stage {stage['stage']} failed: {stage['error']}", err=True)
    typer.echo(f"wrote {', '.join(str(p) for p in paths.values())}")
    if "plot" not in paths:
        typer.echo('no speed_vs_error.png: pip install "frictionfit[plots]" draws it', err=True)
    if any("error" in s for s in stages):
        raise typer.Exit(1)
