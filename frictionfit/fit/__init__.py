"""Batched per-trial least-squares fits of the contact-model family.

The default solver is frictionfit's batched Levenberg-Marquardt
(:mod:`frictionfit.fit._lm`, built from lineax pieces); the optimistix solvers
(LM, dogleg, Gauss-Newton) stay selectable with ``solver=``. Results are in
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

__all__ = ["SOLVERS", "BatchedLevenbergMarquardt", "FitResult", "fit_report", "fit_trials",
           "initial_guess", "plot_fit"]
