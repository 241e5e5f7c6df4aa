"""Which solver a per-trial fit (:func:`~frictionfit.fit.fit_trials`) runs: one of
:data:`SOLVERS` by name or an optimistix least-squares solver as given, with its step
budget, pool size and host threads."""

from __future__ import annotations

from dataclasses import dataclass

import optimistix as optx

from frictionfit._system import available_cores
from frictionfit.errors import FitError
from frictionfit.fit.solver import DATA_ATOL, DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt

__all__ = ["SOLVERS", "SolverSettings", "solver_settings"]

SOLVERS = ("lm", "optx-lm", "dogleg", "gauss-newton")


@dataclass(frozen=True)
class SolverSettings:
    """How each member is solved: the solver (and its name), step budget and pools."""

    name: str
    solver: optx.AbstractLeastSquaresSolver
    max_steps: int
    segment: int  # steps per compiled call, between refills of the pool
    chunk_size: int
    threads: int


def solver_settings(solver, rtol, atol, ftol, max_steps, steps_per_round, chunk_size,
                    threads) -> SolverSettings:
    """The solver object and its name: a name from SOLVERS with the tolerances given (None:
    the data defaults), or an object as given (it brings its own: none may be given beside
    it)."""
    if isinstance(solver, str):
        rtol = DATA_RTOL if rtol is None else rtol
        atol = DATA_ATOL if atol is None else atol
        ftol = DATA_FTOL if ftol is None else ftol
        named = {"lm": lambda: BatchedLevenbergMarquardt(rtol=rtol, ftol=ftol),
                 "optx-lm": lambda: optx.LevenbergMarquardt(rtol=rtol, atol=atol),
                 "dogleg": lambda: optx.Dogleg(rtol=rtol, atol=atol),
                 "gauss-newton": lambda: optx.GaussNewton(rtol=rtol, atol=atol)}
        if solver not in named:
            raise FitError(f"unknown solver {solver!r}; choose from {SOLVERS} or give an "
                           "optimistix least-squares solver")
        name, solver = solver, named[solver]()
    elif isinstance(solver, optx.AbstractLeastSquaresSolver):
        given = [n for n, v in (("rtol", rtol), ("atol", atol), ("ftol", ftol)) if v is not None]
        if given:
            raise FitError(f"{', '.join(given)} given beside a solver object: give the "
                           f"tolerances to {type(solver).__name__} itself")
        name = _NAMES.get(type(solver), type(solver).__name__)
    else:
        raise FitError(f"solver must be a name from {SOLVERS} or an optimistix "
                       f"least-squares solver, not {type(solver).__name__}")
    threads = available_cores() if threads is None else max(int(threads), 1)
    return SolverSettings(
        name=name, solver=solver, max_steps=max_steps, segment=steps_per_round,
        chunk_size=chunk_size,
        threads=threads if isinstance(solver, BatchedLevenbergMarquardt) else 1)


#: The names of SOLVERS' solver classes, for FitResult.solver.
_NAMES = {BatchedLevenbergMarquardt: "lm", optx.LevenbergMarquardt: "optx-lm",
          optx.Dogleg: "dogleg", optx.GaussNewton: "gauss-newton"}
