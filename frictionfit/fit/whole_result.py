"""The result of a whole fit: :class:`MeasurementFit`, a :class:`FitResult` that owns its
data.

One row per recording and channel. Besides the per-row statistics every
:class:`~frictionfit.fit.result.FitResult` has, it keeps each row's model (law, stroke and
priors), the data as fitted (:class:`~frictionfit.fit.measurement_data.MeasurementData`
with each movement's timing as the fit found it, and the block weights) and the noise the
one likelihood holds (:mod:`frictionfit.fit._noise`), so its curves, per-motion refits and
posteriors need nothing passed again.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.fit.result import FitResult, fit_report
from frictionfit.models import PARAMS

__all__ = ["MeasurementFit", "travel_unit"]


def travel_unit(name: str, model_stroke_mm: float,
                declared_mm: float | None) -> tuple[str, float]:
    """Parameter ``name``'s reported unit, and the factor from its fitted value to it.

    A whole fit measures travel in its model's stroke (``model_stroke_mm`` per movement).
    Where the recording declares its rig's stroke (``declared_mm``, mm) a quantity per mm
    is reported per mm of fingertip travel (times ``model_stroke_mm / declared_mm``) and a
    length in mm (times the inverse). Where it declares none and the model's stroke is the
    nominal 1, the unit says what the value is: per stroke (``"N/stroke"``), not per mm.
    """
    unit = PARAMS[name].unit
    if "mm" not in unit:
        return unit, 1.0
    if declared_mm is None:
        return (unit.replace("mm", "stroke"), 1.0) if model_stroke_mm == 1.0 else (unit, 1.0)
    ratio = model_stroke_mm / declared_mm
    return unit, ratio if "/mm" in unit else 1.0 / ratio


@dataclass(repr=False)
class MeasurementFit(FitResult):
    """Per-row results of a whole fit (see :class:`~frictionfit.fit.result.FitResult` for
    the statistics), with what they were fitted to.

    Attributes
    ----------
    items : list of MeasurementData
        Per row, the channel as fitted: blocks ``t`` (s), ``y`` (N) and ``weight``, and
        the drive with each movement's own onset and duration.
    fitted_models : list of MeasurementModel
        Per row, the model fitted (law, stroke, priors).
    noise_sd, noise_rho : ndarray
        Per row, the AR(1) noise of the weighted block residuals at the optimum (marginal
        sd, N, and lag-1 coefficient; :mod:`frictionfit.fit._noise`): the one likelihood's
        noise, behind the BIC, the covariance and the posteriors.
    held_cov : list of ndarray or None
        Per row, the share of ``cov`` that values held at the session's (the motor's profile,
        the finger's creep) add for their own uncertainty (the free parameters' unconstrained
        coordinates; zeros where nothing is held): ``cov`` less it is the covariance at the
        held values.
    density_cov : list of ndarray or None
        Per row, the inverse Gauss-Newton Hessian at the optimum of the log density emcee
        samples (``-|residual|^2 / (2 noise_var)``, at the held values; same coordinates):
        ``cov`` less ``held_cov`` is the sandwich around the same optimum
        (:mod:`frictionfit.fit._noise`), to which emcee's draws are carried.
    derived_grad : list of ndarray or None
        Per row, the gradients of the derived levels (:data:`~frictionfit.fit.derived.LEVELS`,
        rows) with respect to the free unconstrained coordinates (columns, those of ``cov``):
        what :meth:`quantity_cov` needs beyond ``cov``.
    item_of, motion_of : ndarray or None
        For :meth:`per_motion`'s result: per row, the row of the whole fit it refits and
        the motion's number in it.
    """

    drive: str = "measurement"
    items: list[MeasurementData] | None = field(default=None, repr=False)
    fitted_models: list | None = field(default=None, repr=False)
    noise_sd: np.ndarray | None = field(default=None, repr=False)
    noise_rho: np.ndarray | None = field(default=None, repr=False)
    held_cov: list | None = field(default=None, repr=False)
    density_cov: list | None = field(default=None, repr=False)
    derived_grad: list | None = field(default=None, repr=False)
    item_of: np.ndarray | None = field(default=None, repr=False)
    motion_of: np.ndarray | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        return "Measurement" + super().__repr__()

    @property
    def noise_var(self) -> np.ndarray:
        """Per row, the long-run variance of its noise (N^2): the variance per weighted
        block residual of the log density whose curvature is :attr:`density_cov`."""
        from frictionfit.fit._noise import long_run_variance

        return long_run_variance(self.noise_sd, self.noise_rho)

    @property
    def ids(self) -> list[str]:
        """``recording/channel`` of each row (with ``#motion`` for a per-motion result)."""
        names = [f"{d.name}/{d.channel}" for d in self.items]
        if self.motion_of is None:
            return names
        return [f"{n}#{m}" for n, m in zip(names, self.motion_of, strict=True)]

    def member(self, i: int):
        """Row ``i``'s :class:`~frictionfit.models.MeasurementModel`."""
        return self.fitted_models[i]

    def unit(self, i: int, name: str) -> tuple[str, float]:
        """Parameter ``name``'s unit in row ``i``'s tables and report, and the factor from
        its value in :attr:`values` to it (:func:`travel_unit`: mm of fingertip travel where
        the recording declares its rig's stroke, "stroke" where it does not)."""
        return travel_unit(name, self.member(i).stroke_mm, self.items[i].stroke_mm)

    def predict(self, i: int, t=None) -> np.ndarray:
        """The fitted channel (N) of row ``i`` at increasing times ``t`` (s from the
        recording's start; default: the fitted blocks' times)."""
        import jax.numpy as jnp

        d = self.items[i]
        t = d.t if t is None else np.asarray(t, dtype=np.float64)
        return np.asarray(self.member(i).predict(
            jnp.asarray(self.u[i]), jnp.asarray(t), jnp.asarray(d.commands),
            jnp.asarray(d.signs), d.direction, stretch=jnp.asarray(d.stretch)))

    def quantity_cov(self, i: int, names: Sequence[str]) -> np.ndarray:
        """Joint covariance of row ``i``'s named quantities, by the delta method from
        ``cov[i]``: parameters (in the units of :attr:`values`; a held one's row is 0) and
        derived quantities (:data:`~frictionfit.fit.derived.DERIVED`, their units).
        ``slip_noise`` is read off the residuals, not the parameters: its variance is its
        stderr squared, its covariances 0."""
        from frictionfit.fit._numerics import fd_slope
        from frictionfit.fit.derived import LEVELS

        model = self.member(i)
        free = [model.param_names.index(n) for n in self.free_names(i)]
        u, cov = np.asarray(self.u[i]), np.asarray(self.cov[i])
        grad = np.zeros((len(names), len(free)))
        for a, name in enumerate(names):
            if name in LEVELS:
                if self.derived_grad is None:
                    raise ValueError(f"{name}: this fit computed no derived quantities")
                grad[a] = self.derived_grad[i][LEVELS.index(name)]
            elif name in model.param_names:
                j = model.param_names.index(name)
                if j in free:
                    slope = fd_slope(model.params[j].to_physical, u[j:j + 1])
                    grad[a, free.index(j)] = slope[0]
            elif name != "slip_noise":
                raise KeyError(f"{name!r} is neither a parameter of {model.name!r} nor derived")
        out = grad @ cov @ grad.T
        for a, name in enumerate(names):
            if name == "slip_noise":
                out[a, :] = out[:, a] = 0.0
                out[a, a] = self.derived[i]["slip_noise"][1] ** 2
        return out

    def report(self, i: int = 0, min_correl: float = 0.1) -> str:
        """Row ``i``'s lmfit-style report (:func:`~frictionfit.fit.result.fit_report`)."""
        return fit_report(self, i, min_correl)

    def residuals(self, i: int) -> np.ndarray:
        """Row ``i``'s weighted block residuals ``weight (predict - y)`` (N; 0 where a block
        is not fitted)."""
        d = self.items[i]
        return np.where(d.mask, d.weight * (self.predict(i) - d.y), 0.0)

    def noise_by_regime(self) -> pd.DataFrame:
        """The residuals' noise by regime, a check of the one AR(1) the fit assumes
        (:attr:`noise_sd`, :attr:`noise_rho`): per row and regime (``"moving"``: the fitted
        drive's velocity is non-zero; ``"holding"``: it is zero), the fitted blocks, and
        the AR(1) estimate of their weighted residuals (:meth:`residuals`; a block whose
        predecessor is of the other regime starts a new run): ``sd`` (N) and ``rho``."""
        import jax.numpy as jnp

        from frictionfit.fit._noise import ar1_estimate

        rows = []
        for i in range(self.n_trials):
            d = self.items[i]
            _, speed = self.member(i).finger(jnp.asarray(self.u[i]), jnp.asarray(d.t),
                                             jnp.asarray(d.commands), jnp.asarray(d.signs),
                                             jnp.asarray(d.stretch))
            moving, resid = np.asarray(speed) != 0.0, self.residuals(i)
            for regime, where in (("moving", moving), ("holding", ~moving)):
                mask = d.mask & where
                sd, rho = ar1_estimate(resid[None], mask[None])
                rows.append({"id": self.ids[i], "regime": regime, "blocks": int(mask.sum()),
                             "sd": float(sd[0]), "rho": float(rho[0])})
        return pd.DataFrame(rows)

    def plot(self, i: int, path: str | Path, title: str | None = None) -> Path:
        """A PNG of row ``i``'s fitted blocks against its fit, with residuals, at ``path``."""
        from frictionfit.fit.plot import plot_fit

        d = self.items[i]
        return plot_fit(self, i, d.t[d.mask], d.y[d.mask], path,
                        title=title or self.ids[i])

    def per_motion(self, *, max_steps: int = 100, pool_size: int = 16,
                   progress: bool | None = False) -> MeasurementFit:
        """Each fitted motion of each row refitted on its own (rig, sensor and ``wear``
        held at the whole fit's values, from its optimum): one row per motion, with
        :attr:`item_of` and :attr:`motion_of` (:func:`~frictionfit.fit.motions.
        refit_motions`)."""
        from frictionfit.fit.motions import refit_motions

        return refit_motions(self, max_steps=max_steps, pool_size=pool_size,
                             progress=progress)
