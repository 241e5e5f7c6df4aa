"""The ``frictionfit`` command line: one thin module per command.

Command modules import only typer at the top; heavy imports (JAX, scikit-learn)
happen inside the command, so ``frictionfit --help`` is instant.
"""

from __future__ import annotations

import typer

from frictionfit.cli import acquire, bench, classify, demo, fit, info, plot, simulate

app = typer.Typer(
    name="frictionfit",
    help=(
        "Fit physical stick-slip / relaxation contact models to tactile rubbing "
        "recordings, and recognise materials with interpretable features.\n\n"
        "Start with `frictionfit demo`; every command has its own --help."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help: wrapped, never cut at 80 columns
)
_COMMANDS = (  # name, function, the one line in `frictionfit --help`
    ("demo", demo.demo, "The tour on the sample data: read, segment, fit, classify."),
    ("info", info.info, "Summarise a recording or a dataset and its problems."),
    ("plot", plot.plot, "PNG of a recording with its phases and missing samples."),
    ("fit", fit.fit, "Fit the contact model: each recording whole, or --motions."),
    ("features", classify.features, "Write a feature table, one row per recording."),
    ("train", classify.train, "Train a classifier and save it (skops)."),
    ("predict", classify.predict, "Classify recordings with a saved model."),
    ("evaluate", classify.evaluate, "Score a pipeline under a protocol (e.g. per session)."),
    ("acquire", acquire.acquire, "Record OptoForce sensors without losing a sample."),
    ("rub", acquire.rub, "Run the rubbing protocol on a gripper while recording."),
    ("bench", bench.bench, "Benchmark speed against error on simulated data."),
)


@app.callback()
def _plain_warnings() -> None:
    """Warnings reach the user as one ``warning: ...`` line each on stderr, said once: not
    Python's raw ``file:line: Category: ...`` lines (only their formatting changes: code that
    records warnings still receives them)."""
    import warnings

    seen: set[str] = set()

    def plain(message, category, filename, lineno, line=None) -> str:
        text = " ".join(str(message).split())
        if text in seen:
            return ""
        seen.add(text)
        return f"warning: {text}\n"

    warnings.formatwarning = plain


for _name, _func, _line in _COMMANDS:
    app.command(_name, short_help=_line)(_func)
app.add_typer(simulate.app, name="simulate",
              short_help="Simulate measurements or touch gestures with known truth.")


def main() -> None:
    """Entry point of the console script; a missing optional dependency ends the command
    with the ``pip install`` line that brings it (exit code 1)."""
    from frictionfit._optional import MissingExtraError

    try:
        app()
    except MissingExtraError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise SystemExit(1) from None
