"""Posterior uncertainties of fitted contact-model parameters: Laplace and emcee.

:func:`sample_posterior` (in :mod:`~frictionfit.uncertainty.engine`) returns a
:class:`Posterior` per trial of a :class:`~frictionfit.fit.FitResult`;
:func:`whole_fit_posterior` (in :mod:`~frictionfit.uncertainty.measurement`) does the
same for a whole fit (:class:`~frictionfit.fit.MeasurementFit`, its covariance the
sandwich around its optimum); both evaluate the one AR(1) likelihood of
:mod:`frictionfit.fit._noise`.
"""

from frictionfit.uncertainty.engine import AUTO_MAX_COND as AUTO_MAX_COND
from frictionfit.uncertainty.engine import AUTO_MAX_PROFILE_DEV as AUTO_MAX_PROFILE_DEV
from frictionfit.uncertainty.engine import METHODS as METHODS
from frictionfit.uncertainty.engine import sample_posterior as sample_posterior
from frictionfit.uncertainty.measurement import measurement_posterior as measurement_posterior
from frictionfit.uncertainty.measurement import whole_fit_posterior as whole_fit_posterior
from frictionfit.uncertainty.posterior import Posterior as Posterior
from frictionfit.uncertainty.posterior import corner_plot as corner_plot
from frictionfit.uncertainty.posterior import posterior_summary as posterior_summary
from frictionfit.uncertainty.posterior import to_arviz as to_arviz

__all__ = ["AUTO_MAX_COND", "AUTO_MAX_PROFILE_DEV", "METHODS", "Posterior", "corner_plot",
           "measurement_posterior", "posterior_summary", "sample_posterior", "to_arviz",
           "whole_fit_posterior"]
