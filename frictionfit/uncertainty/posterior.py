"""Per-trial posterior summaries: the :class:`Posterior` result, tables, arviz and corner."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from frictionfit.models import PARAMS
from frictionfit.models.measurement import model_named
from frictionfit.uncertainty._ensemble import ChainResult

__all__ = ["QUANTILES", "Posterior", "corner_plot", "posterior_summary", "to_arviz"]

#: Reported posterior quantiles (fractions) and their column names.
QUANTILES = {"p2.5": 0.025, "p16": 0.16, "median": 0.5, "p84": 0.84, "p97.5": 0.975}


@dataclass
class Posterior:
    """Posterior of every trial of a fit, physical units.

    Attributes
    ----------
    model : list of str
        Family member per trial.
    method : list of str
        ``"emcee"``, ``"laplace"`` or ``"none"`` (trial skipped: see ``reason``).
    reason : list of str
        Why that method (the ``auto`` policy's reason) or why the trial was skipped.
    converged : ndarray of bool
        emcee: chain >= 50 tau, tau stable, R-hat over the walkers <= 1.01 on every
        parameter, acceptance checked; Laplace: finite covariance. A False trial's numbers
        are reported but must not be trusted.
    quantiles : list of dict
        Per parameter, the values at :data:`QUANTILES` (physical unit).
    sd, tau, ess, rhat : list of dict
        Per parameter: posterior sd (physical unit), integrated autocorrelation time
        (steps), effective sample size and rank-normalised split R-hat over the walkers
        (the last three NaN for Laplace and for parameters held fixed).
    acceptance : ndarray
        Mean emcee acceptance fraction per trial (NaN for Laplace).
    chains : list
        emcee :class:`ChainResult` per trial (unconstrained), or None.
    wall_s : float
        Wall time of the whole batch, s.
    units : list of dict, optional
        Per trial, ``name -> (unit, factor)`` where a parameter is reported in another unit
        than ``PARAMS[name].unit`` (a whole fit's travel per declared stroke; see
        :meth:`unit`); the quantiles and sd are in it already.
    """

    model: list[str]
    method: list[str]
    reason: list[str]
    converged: np.ndarray
    quantiles: list[dict]
    sd: list[dict]
    tau: list[dict]
    ess: list[dict]
    rhat: list[dict]
    acceptance: np.ndarray
    chains: list[ChainResult | None] = field(repr=False)
    wall_s: float = 0.0
    units: list[dict] | None = field(default=None, repr=False)

    @property
    def n_trials(self) -> int:
        return len(self.model)

    def unit(self, i: int, name: str) -> tuple[str, float]:
        """Parameter ``name``'s unit in trial ``i``'s results, and the factor from the
        model's physical value (``PARAMS[name].unit``) to it."""
        given = self.units[i].get(name) if self.units is not None else None
        return given or (PARAMS[name].unit, 1.0)

    def verdict(self) -> str:
        """One line for a log: the rows per method, and how many emcee chains converged
        (with the largest R-hat of those that did not)."""
        parts = []
        for method in ("laplace", "emcee", "none"):
            rows = [i for i, m in enumerate(self.method) if m == method]
            if not rows:
                continue
            count = f"{len(rows)} row{'s' if len(rows) > 1 else ''}"
            text = {"laplace": f"Laplace on {count}", "emcee": f"emcee on {count}",
                    "none": f"{count} skipped (see uq_reason)"}[method]
            if method == "emcee":
                failed = [i for i in rows if self.chains[i] is None]
                stuck = [i for i in rows if not self.converged[i] and i not in failed]
                text += f" ({len(rows) - len(stuck) - len(failed)} converged"
                if stuck:
                    worst = max(np.nanmax([*self.rhat[i].values(), np.nan]) for i in stuck)
                    text += (f"; the others' largest R-hat {worst:.2f}: their intervals are "
                             "not to be trusted, see uq_reason")
                if failed:
                    text += f"; {len(failed)} failed: {self.reason[failed[0]]}"
                text += ")"
            parts.append(text)
        return ", ".join(parts)

    def samples(self, i: int) -> pd.DataFrame:
        """Post-burn-in, thinned emcee draws of trial ``i`` in physical units."""
        chain = self.chains[i]
        if chain is None:
            raise ValueError(f"trial {i} has no emcee chain (method {self.method[i]!r})")
        flat = chain.samples.reshape(-1, chain.samples.shape[-1])
        model = model_named(self.model[i])
        return pd.DataFrame({p.name: np.asarray(p.to_physical(flat[:, j])) * self.unit(i, p.name)[1]
                             for j, p in enumerate(model.params)})

    def to_frame(self, ids=None) -> pd.DataFrame:
        """One row per trial: method, converged, and per parameter each quantile, sd, tau,
        ESS and R-hat."""
        rows = []
        for i in range(self.n_trials):
            row = {"trial": i if ids is None else ids[i], "uq_method": self.method[i],
                   "uq_reason": self.reason[i], "uq_converged": bool(self.converged[i]),
                   "uq_acceptance": self.acceptance[i]}
            for name, q in self.quantiles[i].items():
                unit = self.unit(i, name)[0]
                for key, v in zip(QUANTILES, q, strict=True):
                    row[f"{name}_{key} [{unit}]"] = v
                row[f"{name}_sd [{unit}]"] = self.sd[i][name]
                row[f"{name}_tau [steps]"] = self.tau[i][name]
                row[f"{name}_ess"] = self.ess[i][name]
                row[f"{name}_rhat"] = self.rhat[i][name]
            rows.append(row)
        return pd.DataFrame(rows)


class SummaryTable(pd.DataFrame):
    """A DataFrame that prints every row and column (``print`` shows sd, tau, ESS and
    R-hat too)."""

    @property
    def _constructor(self):
        return SummaryTable

    def __repr__(self) -> str:
        return self.to_string()

    __str__ = __repr__


def posterior_summary(post: Posterior, ids=None) -> SummaryTable:
    """Long table, one row per trial x parameter, for features and reports.

    Columns: ``trial, model, param, unit, method, converged, median, sd, p2.5,
    p16, p84, p97.5, tau, ess, rhat, acceptance`` (values in the parameter's unit).
    Use ``median`` with ``sd`` (e.g. inverse-variance weights ``1/sd**2``) and
    drop or down-weight rows with ``converged == False``. Printed whole.
    """
    rows = []
    for i in range(post.n_trials):
        for name, q in post.quantiles[i].items():
            row = {"trial": i if ids is None else ids[i], "model": post.model[i], "param": name,
                   "unit": post.unit(i, name)[0], "method": post.method[i],
                   "converged": bool(post.converged[i]), "sd": post.sd[i][name],
                   "tau": post.tau[i][name], "ess": post.ess[i][name],
                   "rhat": post.rhat[i][name],
                   "acceptance": post.acceptance[i]}
            row.update(zip(QUANTILES, q, strict=True))
            rows.append(row)
    return SummaryTable(rows)


def to_arviz(post: Posterior, i: int = 0):
    """An ``arviz.InferenceData`` of trial ``i``'s emcee chains (physical units).

    ``arviz.summary(to_arviz(post, i))`` gives its own ESS and R-hat per parameter.
    """
    chain = post.chains[i]
    if chain is None:
        raise ValueError(f"trial {i} has no emcee chain (method {post.method[i]!r})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # arviz announces its refactor
        from frictionfit._optional import require

        az = require("arviz", "to_arviz")
    model = model_named(post.model[i])
    # emcee chains are (step, walker, p); arviz wants (chain=walker, draw=step).
    draws = {p.name: np.asarray(p.to_physical(chain.samples[:, :, j].T))
             for j, p in enumerate(model.params)}
    return az.from_dict(posterior=draws)


def corner_plot(post: Posterior, i: int, path) -> None:
    """Write a ``corner`` plot (PNG) of trial ``i``'s emcee posterior, physical units."""
    from frictionfit._optional import pyplot, require

    corner = require("corner", "corner_plot")
    plt = pyplot("corner_plot")

    draws = post.samples(i)
    draws = draws.loc[:, draws.nunique() > 1]  # parameters held fixed have no range to plot
    labels = [f"{n} [{post.unit(i, n)[0]}]" for n in draws.columns]
    fig = corner.corner(draws.to_numpy(), labels=labels, quantiles=[0.16, 0.5, 0.84])
    fig.savefig(path, dpi=80)
    plt.close(fig)
