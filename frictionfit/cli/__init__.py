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
)
app.command("demo")(demo.demo)
app.command("info")(info.info)
app.add_typer(simulate.app, name="simulate")
app.command("plot")(plot.plot)
app.command("fit")(fit.fit)
app.command("features")(classify.features)
app.command("train")(classify.train)
app.command("predict")(classify.predict)
app.command("evaluate")(classify.evaluate)
app.command("acquire")(acquire.acquire)
app.command("rub")(acquire.rub)
app.command("bench")(bench.bench)


def main() -> None:
    """Entry point of the console script."""
    app()
