"""Least-squares fits of the contact-model family: single strokes and whole measurements.

:func:`fit_trials` fits single strokes (:class:`Trials`, one row per stroke and channel)
and returns a :class:`FitResult`; :class:`MeasurementFit` is the result of a whole fit of
recordings (:func:`frictionfit.fit_recordings`, which adds its posterior), one row per
recording and channel (:class:`MeasurementData`, :func:`measurement_data`). The default
solver is frictionfit's Levenberg-Marquardt (:class:`BatchedLevenbergMarquardt`, built
from lineax pieces); for strokes, optimistix's LM, dogleg and Gauss-Newton, or any
optimistix least-squares solver, are selectable with ``solver=``, and all run in the same
refilled pools of slots. Results are in physical units with lmfit-style statistics,
identifiability flags and a status per row.
"""

from frictionfit.fit._batch import fit_trials as fit_trials
from frictionfit.fit._guess import initial_guess as initial_guess
from frictionfit.fit._solver_choice import SOLVERS as SOLVERS
from frictionfit.fit.measurement_data import MeasurementData as MeasurementData
from frictionfit.fit.measurement_data import measurement_data as measurement_data
from frictionfit.fit.plot import plot_fit as plot_fit
from frictionfit.fit.result import FitResult as FitResult
from frictionfit.fit.result import fit_report as fit_report
from frictionfit.fit.solver import BatchedLevenbergMarquardt as BatchedLevenbergMarquardt
from frictionfit.fit.trials import Trials as Trials
from frictionfit.fit.whole_result import MeasurementFit as MeasurementFit

__all__ = ["SOLVERS", "BatchedLevenbergMarquardt", "FitResult", "MeasurementData",
           "MeasurementFit", "Trials", "fit_report", "fit_trials", "initial_guess",
           "measurement_data", "plot_fit"]
