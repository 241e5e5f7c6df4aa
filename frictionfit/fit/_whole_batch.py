"""One batched whole fit of one law: :func:`fit_batch`, and its statistics at the optimum.

The pools run in one host thread (:func:`~frictionfit.fit._optx.solve_pooled`): the
contact simulation's Jacobian is a compiled loop that shares its rows over the cores
itself. At the optimum the AR(1) noise of the weighted block residuals is estimated
(:func:`~frictionfit.fit._noise.ar1_estimate`). The log density ``-|residual|^2 / (2 s2)``,
``s2`` the noise's long-run variance (:func:`~frictionfit.fit._noise.long_run_variance`),
has its inverse Gauss-Newton Hessian as the density's covariance (its ridges checked along
it, emcee's start); the fit's covariance is the sandwich ``A^+ S A^+`` (``A`` the
Gauss-Newton ``J^T J``, ``S`` the long-run covariance of the blocks' scores:
:func:`~frictionfit.fit._whole_problem.score_covariances`), the held values' share added.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from functools import lru_cache

import numpy as np
from tqdm.auto import tqdm

from frictionfit.errors import Status
from frictionfit.fit._noise import ar1_estimate, long_run_variance
from frictionfit.fit._numerics import scaled_condition
from frictionfit.fit._optx import solve_pooled
from frictionfit.fit._stats import VANISHING, flag_gated, set_covariance, statistics, status_of
from frictionfit.fit._whole_problem import (
    WholeFitData,
    normal_fn,
    profile_drops,
    residual_fn,
    residuals_at,
    score_covariances,
    stack_items,
)
from frictionfit.fit.derived import derived_quantities
from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.fit.result import param_table
from frictionfit.fit.solver import BatchedLevenbergMarquardt
from frictionfit.fit.whole_result import MeasurementFit
from frictionfit.models import PARAMS, MeasurementModel
from frictionfit.models.measurement import (
    HOST_LOOP_COMPILER_OPTIONS,
    jit_host_loop,
    to_unconstrained,
)
from frictionfit.models.stick_slip import maxwell_branches

__all__ = ["FIRST_PASS", "PROFILE_MIN_DROP", "RESTART_FRACTION", "UNPOLISHED",
           "WHOLE_FIT_SOLVER", "fit_batch", "with_solver_tolerances"]

#: The solver of a whole fit's final passes (its tolerances: relative, MINPACK's ``ftol``
#: and ``xtol``). A first pass that a second one polishes runs at ten times its
#: ``ftol`` and ``rtol``; a fit that nothing polishes at a tenth of them.
WHOLE_FIT_SOLVER = BatchedLevenbergMarquardt(ftol=1e-5, rtol=1e-7)
#: Factors on the solver's tolerances for a first pass, and for a fit nothing polishes.
FIRST_PASS, UNPOLISHED = 10.0, 0.1


def _start(model: MeasurementModel, items: Sequence[MeasurementData], fix: Mapping,
           u0: np.ndarray | None) -> tuple[np.ndarray, tuple[int, ...]]:
    """Full unconstrained starting points (the data's guess, or ``u0``) with the held values
    set, and the free parameters' indices."""
    unknown = [n for n in fix if n not in model.param_names]
    if unknown:
        raise ValueError(f"cannot fix {unknown}: parameters are {list(model.param_names)}")
    base = (np.stack([to_unconstrained(model, d.guess) for d in items]) if u0 is None
            else np.array(u0, dtype=np.float64))
    for name, value in fix.items():
        j = model.param_names.index(name)
        base[:, j] = model.params[j].to_unconstrained(np.broadcast_to(value, (len(items),)))
    return base, tuple(j for j, n in enumerate(model.param_names) if n not in fix)


def fit_batch(items: Sequence[MeasurementData], *, model: MeasurementModel,
              solver: BatchedLevenbergMarquardt, fix: Mapping | None, u0: np.ndarray | None,
              max_steps: int, pool_size: int, progress: bool | None, final: bool = True,
              restart: bool = True, held_cov: np.ndarray | None = None) -> MeasurementFit:
    """One batched fit of ``items`` with ``fix`` (name -> one value per item) held, by
    ``solver`` (its tolerances; its ``normal`` set here) from ``u0`` (default: the data's
    guess). ``final=False`` (a fit another one polishes): no derived quantities, and the
    "trades off" flags are not checked along their profiles. ``restart=False``: no slow
    branch solved again (:func:`_slow_branch_restarted`). ``held_cov``: per item, the
    covariance that held values' own uncertainty adds to the free parameters."""
    fix = dict(fix or {})
    base, free = _start(model, items, fix, u0)
    data = stack_items(items, base)
    residual = residual_fn(model, free)
    solver = replace(solver, normal=normal_fn(model, free))
    branches = not {"relax_frac", "tau", "relax_frac2", "tau2"} & set(fix)

    def solve(start: np.ndarray, rows: np.ndarray, bar=None) -> tuple:
        """The optimum of items ``rows`` from ``start`` (full ``u``, the faster branch put
        first), their status, steps and solver statistics, and which rows were relabelled."""
        u_free, code, steps, stats = solve_pooled(
            solver, residual, start[:, free], data.take(rows), pool_size=pool_size,
            max_steps=max_steps, threads=1, progress=None if bar is None else bar.update,
            solver_stats=True, compiler_options=HOST_LOOP_COMPILER_OPTIONS)
        u = start.copy()
        u[:, free] = u_free
        u, relabelled = (_faster_branch_first(model, u) if branches
                         else (u, np.zeros(len(rows), bool)))
        return u, code, steps, stats, relabelled

    # a bar on a terminal only (tqdm's None), for batches long enough to wait for
    hide = (None if len(items) >= 16 else True) if progress is None else not progress
    desc = model.law if final else f"{model.law}, first pass"
    with tqdm(total=len(items), desc=desc, unit="rec", disable=hide) as bar:
        u, code, steps, at_solution, again = solve(base, np.arange(len(items)), bar)
    if branches and restart:
        again |= _slow_branch_restarted(model, items, solve, u, code, steps, at_solution)
    jtj = _solver_jtj(model, free, u[:, free], data, at_solution["jtj"], again)
    return _result(model, items, data, free, tuple(fix), u, code, steps, jtj, final, held_cov)


def _result(model: MeasurementModel, items: Sequence[MeasurementData], data: WholeFitData,
            free: tuple[int, ...], fixed: tuple[str, ...], u: np.ndarray, code: np.ndarray,
            steps: np.ndarray, jtj: np.ndarray, final: bool, held_cov) -> MeasurementFit:
    """The batch's :class:`MeasurementFit` at its optimum ``u``: statistics (the sandwich
    covariance, the held values' share added), flags, status, derived quantities."""
    resid = residuals_at(model, free, u[:, free], data)
    mask = data.mask
    sigma, rho = ar1_estimate(resid, mask)
    s2 = long_run_variance(sigma, rho)
    stats = statistics(model, u, resid, jtj, mask, free, fixed,
                       hessian=jtj / s2[:, None, None])
    if final:
        _ridges_checked(model, free, u, stats, data, s2)
    density_cov = stats["cov"].copy()
    held_cov = (np.zeros_like(density_cov) if held_cov is None
                else np.asarray(held_cov, dtype=np.float64))
    bread = density_cov / s2[:, None, None]  # pinv(J^T J); NaN where not computed
    meat = score_covariances(model, free, u[:, free], data, resid, rho)
    set_covariance(model, u, stats, free, bread @ meat @ bread + held_cov)
    w2 = data.weight**2
    y_bar = np.sum(w2 * data.y, axis=1) / np.maximum(np.sum(w2, axis=1), 1e-300)
    ss_tot = np.sum(w2 * (data.y - y_bar[:, None]) ** 2, axis=1)
    r2 = 1.0 - stats["chi2"] / np.where(ss_tot > 0, ss_tot, np.nan)
    names = [model.param_names[j] for j in free]
    cond = np.array([_cond_inside(jtj[i], [stats["flags"][i].get(n) not in VANISHING
                                           for n in names]) for i in range(len(items))])
    status = np.array([status_of(len(free), code[i] == Status.CONVERGED, u[i], stats["chi2"][i],
                                 cond[i], mask[i], saturated=items[i].clipped > 0,
                                 flags=stats["flags"][i])
                       for i in range(len(items))])
    derived, derived_grad = (derived_quantities(model, free, u, stats["cov"], resid, items,
                                                data.direction) if final else (None, None))
    return MeasurementFit(
        model=[model.name] * len(items), values=param_table(stats["values"]),
        stderr=param_table(stats["stderr"]), flags=stats["flags"],
        status=status.astype(np.int64), chi2=stats["chi2"], redchi=stats["redchi"],
        aic=stats["aic"], bic=stats["bic"], r2=r2, cond=cond, n_steps=steps,
        ndata=stats["ndata"], nvarys=stats["nvarys"], u=list(u), direction=data.direction,
        init=[_physical_init(model, d.guess) for d in items], correl=stats["correl"],
        cov=list(stats["cov"]), stroke_mm=model.stroke_mm, priors=_prior_dict(model),
        derived=derived, derived_grad=derived_grad,
        items=list(items), fitted_models=[model] * len(items), noise_sd=sigma, noise_rho=rho,
        held_cov=list(held_cov), density_cov=list(density_cov))


#: Smallest drop of the log-posterior 2 sd out on either side of a parameter's Gaussian
#: profile line (its covariance column; the Gaussian predicts a drop of exactly 2) for a
#: parameter that trades off with another to keep its stderr as a (conservative) interval.
PROFILE_MIN_DROP = 1.0


def _ridges_checked(model: MeasurementModel, free: tuple[int, ...], u: np.ndarray,
                    stats: dict, data: WholeFitData, s2: np.ndarray) -> None:
    """Lift (in place) each "trades off with" flag whose parameter's log-posterior falls by
    at least :data:`PROFILE_MIN_DROP` 2 sd out on both sides of its profile line
    (:func:`~frictionfit.fit._whole_problem.profile_drops`): the posterior is then no wider
    there than the Gaussian, and the standard error is an interval that does not overstate
    what the data say. Along a flat or one-sided ridge the drop stays small and the flag
    stays. ``s2``: per item, the long-run noise variance (N^2)."""
    names = [model.param_names[j] for j in free]
    rows = [i for i, flags in enumerate(stats["flags"])
            if any(flags.get(n, "").startswith("trades off") for n in names)
            and np.all(np.isfinite(stats["cov"][i]))]
    drops = profile_drops(model, free, u[:, list(free)], stats["cov"], data, s2, rows)
    for i, drop in zip(rows, drops.min(axis=1), strict=True):
        flags = stats["flags"][i]
        for name, d in zip(names, drop, strict=True):
            if flags.get(name, "").startswith("trades off") and d >= PROFILE_MIN_DROP:
                del flags[name]
        flag_gated(flags, stats["values"][i], stats["stderr"][i])


def _cond_inside(jtj: np.ndarray, inside: list[bool]) -> float:
    """Condition number of the column-scaled ``J^T J`` over the parameters ``inside``.

    A parameter whose column vanishes (:data:`VANISHING`) makes ``J^T J`` singular however
    well the others are determined; it is reported with its flag, and the conditioning that
    matters is the others'.
    """
    a = jtj[np.ix_(np.flatnonzero(inside), np.flatnonzero(inside))]
    return float(scaled_condition(a)) if np.all(np.isfinite(a)) else np.inf


def _physical_init(model: MeasurementModel, guess: dict) -> dict:
    """The starting point in physical units, every parameter (defaults where not guessed)."""
    return {p.name: float(guess.get(p.name, p.default)) for p in model.params}


def _prior_dict(model: MeasurementModel) -> dict | None:
    return None if model.priors is None else dict(model.prior_table)


#: Fraction of the force a slow Maxwell branch pinned at its largest fraction is restarted
#: from (its time: the median interval between commands, one hold): see
#: :func:`_slow_branch_restarted`.
RESTART_FRACTION = 0.2


def _slow_branch_restarted(model: MeasurementModel, items: Sequence[MeasurementData], solve,
                           u: np.ndarray, code: np.ndarray, steps: np.ndarray,
                           at_solution: dict) -> np.ndarray:
    """Solve again each item whose slow branch ended at the largest fraction (``relax_frac2``
    at its upper bound, ``tau2`` seconds long), from the branch at :data:`RESTART_FRACTION`
    relaxing over one hold, and keep the optimum of lower cost (priors included); ``u``,
    ``code``, ``steps`` and the solver's statistics updated in place. Returns which items
    changed. The logistic map is flat at the bound, so a solver that runs there does not
    come back, though a weaker, faster branch often fits better."""
    names = model.param_names
    if "relax_frac2" not in names:
        return np.zeros(len(u), bool)
    j_frac, j_time = names.index("relax_frac2"), names.index("tau2")
    frac = PARAMS["relax_frac2"]
    rows = np.flatnonzero((u[:, j_frac] > 0) & frac.at_bound(frac.to_physical(u[:, j_frac])))
    changed = np.zeros(len(u), bool)
    if rows.size == 0:
        return changed
    start = u[rows].copy()
    start[:, j_frac] = frac.to_unconstrained(RESTART_FRACTION)
    hold = np.array([np.median(np.diff(items[i].commands)) for i in rows])
    slow = PARAMS["tau2"]
    start[:, j_time] = slow.to_unconstrained(np.where(hold > 0, hold, slow.default))
    new_u, new_code, new_steps, new_stats, _ = solve(start, rows)
    better = new_stats["cost"] < at_solution["cost"][rows]
    keep = rows[better]
    u[keep], code[keep] = new_u[better], new_code[better]
    steps[rows] += new_steps
    for name, value in at_solution.items():
        value[keep] = new_stats[name][better]
    changed[keep] = True
    return changed


def _faster_branch_first(model: MeasurementModel, u: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Relabel the two Maxwell branches where ``tau > tau2`` (the same force: branch weights
    ``relax_frac`` and ``relax_frac2 (1 - relax_frac)`` swapped), so ``tau`` is the faster;
    and which rows were relabelled."""
    names = model.param_names
    if "tau2" not in names:
        return u, np.zeros(u.shape[0], bool)
    v = model.physical(u)
    swap = v["tau"] > v["tau2"]
    (w1, w2), _ = maxwell_branches(v["relax_frac"], v["tau"], v["relax_frac2"], v["tau2"])
    new = {"tau": v["tau2"], "tau2": v["tau"], "relax_frac": w2,
           "relax_frac2": w1 / np.maximum(1.0 - w2, 1e-12)}
    u = u.copy()
    for name, value in new.items():
        j = names.index(name)
        u[swap, j] = PARAMS[name].to_unconstrained(value[swap])
    return u, np.asarray(swap)


@lru_cache(maxsize=16)
def _jacobian_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted ``(u_free, data) -> J^T J`` (with the prior rows) of one item."""
    normal = normal_fn(model, free)
    return jit_host_loop(lambda u_free, data: normal(u_free, data)[1])


def _solver_jtj(model: MeasurementModel, free: tuple[int, ...], u_free, data: WholeFitData,
                jtj: np.ndarray, again: np.ndarray) -> np.ndarray:
    """The least-squares ``J^T J`` at ``u_free`` (its conditioning and vanishing columns
    flag the fit): as the solver left it, computed again only for the rows in ``again``
    (relabelled after the fit) or where it is not finite."""
    jtj = np.array(jtj, dtype=np.float64)
    one = _jacobian_fn(model, free)
    for i in np.flatnonzero(again | ~np.all(np.isfinite(jtj), axis=(1, 2))):
        jtj[i] = np.asarray(one(u_free[i], data.take(i)))
    return jtj


def with_solver_tolerances(solver: BatchedLevenbergMarquardt, factor: float
                           ) -> BatchedLevenbergMarquardt:
    """``solver`` with its step and cost tolerances (``rtol``, ``ftol``) times ``factor``."""
    return replace(solver, rtol=solver.rtol * factor, ftol=solver.ftol * factor)

