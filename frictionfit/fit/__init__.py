"""Batched per-trial least-squares fits of the contact-model family.

The default solver is frictionfit's Levenberg-Marquardt
(:class:`BatchedLevenbergMarquardt`, built from lineax pieces); optimistix's LM,
dogleg and Gauss-Newton, or any optimistix least-squares solver, are selectable with
``solver=``, and all run in the same refilled pools of slots. Results are in
physical units with lmfit-style statistics, identifiability flags and a status
per trial.
"""

from frictionfit.fit._batch import SOLVERS as SOLVERS
from frictionfit.fit._batch import fit_trials as fit_trials
from frictionfit.fit._guess import initial_guess as initial_guess
from frictionfit.fit.plot import plot_fit as plot_fit
from frictionfit.fit.result import FitResult as FitResult
from frictionfit.fit.result import fit_report as fit_report
from frictionfit.fit.solver import BatchedLevenbergMarquardt as BatchedLevenbergMarquardt
from frictionfit.fit.trials import Trials as Trials

__all__ = ["SOLVERS", "BatchedLevenbergMarquardt", "FitResult", "Trials", "fit_report",
           "fit_trials", "initial_guess", "plot_fit"]
