"""Numerical stability: run the hard-case gallery through the fit and judge every trial.

Each trial is judged twice, on the least-squares fit and on its Laplace
posterior (:func:`frictionfit.uncertainty.sample_posterior`). An outcome is one of

- ``correct``: converged, and every checked parameter within the case's tolerance;
- ``flagged``: an explicit answer that the data cannot give the number: a status
  other than converged, or the checked parameter flagged (not identifiable);
- ``confident_wrong``: converged, not flagged, and outside the tolerance;
- ``silent_nan``: a non-finite value or standard error with neither status nor flag;
- ``error``: an exception escaped the batch.

A case passes when each trial's outcome is one the case accepts, its repeated
trials are bit-identical (where it has them), and the Jacobian of the model is
finite at the truth and at the fitted point of every trial.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.errors import Status
from frictionfit.fit import FitResult, Trials, fit_trials
from frictionfit.fit.result import take_trials
from frictionfit.models import get_model
from frictionfit.simulation.hard_cases import HardCase, hard_cases, truth_unconstrained

__all__ = ["CaseFit", "TrialOutcome", "fit_cases", "judge", "run"]

#: Trials per vmapped chunk; every group of cases pads to it, so one compile per model.
CHUNK = 16


@dataclass(frozen=True)
class TrialOutcome:
    """The verdict on one trial of one hard case: the fit's outcome and the Laplace posterior's.

    ``passed``: the fit's outcome is acceptable for the case, repeated trials are
    bit-identical and the Jacobian finite. ``laplace_passed``: the posterior's
    outcome is acceptable (it counts as right when the truth is within the case's
    tolerance + POSTERIOR_SDS sd of its median) or the posterior was not run.
    """

    case: str
    trial: int
    status: str
    outcome: str
    passed: bool
    detail: str
    laplace: str = "not_run"
    laplace_passed: bool = True
    laplace_detail: str = ""


def _groups(cases: Mapping[str, HardCase]) -> dict[tuple, list[str]]:
    """Cases that can share one ``fit_trials`` call: same model, length, dtype, start policy."""
    groups: dict[tuple, list[str]] = {}
    for name, c in cases.items():
        key = (c.trials.model, c.trials.t.size, c.trials.y.dtype.str, c.u0 is not None)
        groups.setdefault(key, []).append(name)
    return groups


def _trials(group: list[HardCase]) -> Trials:
    """The trials of every case of ``group`` (one time grid), in order, as the fit takes them."""
    sets = [c.trials for c in group]
    t_out = np.concatenate([np.full(s.n_trials, s.t_out) for s in sets])
    t_back = np.concatenate([np.full(s.n_trials, s.t_back) for s in sets])
    return Trials.from_arrays(np.concatenate([s.y for s in sets]), sets[0].t, (t_out, t_back))


def _fit_group(group: list[HardCase], trials: Trials, solver: str, max_steps: int) -> FitResult:
    first = group[0]
    u0 = None if first.u0 is None else np.concatenate([c.u0 for c in group])
    return fit_trials(trials, model=first.trials.model, solver=solver, max_steps=max_steps,
                      chunk_size=CHUNK, u0=u0)


@dataclass(frozen=True)
class CaseFit:
    """One case's rows of a batched fit (and of its Laplace posterior, when run).

    ``post_median``/``post_sd`` are per-trial dicts (physical units), ``None`` when
    the uncertainty was not run; ``post_error`` is the exception text if it raised.
    """

    status: np.ndarray
    values: list[dict]
    stderr: list[dict]
    flags: list[dict]
    u: list[np.ndarray]
    post_median: list[dict] | None = None
    post_sd: list[dict] | None = None
    post_converged: np.ndarray | None = None
    post_error: str = ""


def _laplace(fit: FitResult, trials: Trials):
    """Laplace posterior of one case's fit: ``(median, sd, converged)``, or the error text."""
    try:
        from frictionfit.uncertainty import sample_posterior
    except ImportError as exc:
        return f"uncertainty unavailable: {exc}"
    try:
        post = sample_posterior(fit, trials, method="laplace")
    except Exception as exc:  # noqa: BLE001 - an escaped exception is an outcome
        return f"{type(exc).__name__}: {exc}"
    median = [{k: float(q[k][2]) for k in q} for q in post.quantiles]  # QUANTILES: 2 = median
    return median, post.sd, np.asarray(post.converged)


def _case_fit(fit: FitResult, trials: Trials, uncertainty: bool) -> CaseFit:
    post = _laplace(fit, trials) if uncertainty else None
    extra = {"post_error": post} if isinstance(post, str) else {} if post is None else {
        "post_median": post[0], "post_sd": post[1], "post_converged": post[2]}
    return CaseFit(np.asarray(fit.status), [fit.params(i) for i in range(fit.n_trials)],
                   [fit.stderrs(i) for i in range(fit.n_trials)], fit.flags, list(fit.u),
                   **extra)


def _run_group(group: list[HardCase], solver: str, max_steps: int,
               uncertainty: bool) -> list[CaseFit]:
    trials = _trials(group)
    fit = _fit_group(group, trials, solver, max_steps)
    bounds = np.cumsum([0] + [c.n_trials for c in group])
    return [_case_fit(take_trials(fit, slice(a, b)), trials.take(slice(a, b)), uncertainty)
            for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def fit_cases(cases: Mapping[str, HardCase], *, solver: str = "lm", max_steps: int = 200,
              uncertainty: bool = True) -> dict[str, CaseFit | Exception]:
    """Fit every case (and its Laplace posterior), batching compatible cases into one call.

    An exception is kept as the case's result, not raised: when a batched call
    raises, its cases are refitted one by one so that the exception is pinned on
    the case that causes it.
    """
    results: dict[str, CaseFit | Exception] = {}
    for names in _groups(cases).values():
        group = [cases[n] for n in names]
        try:
            results.update(zip(names, _run_group(group, solver, max_steps, uncertainty),
                               strict=True))
        except Exception:  # noqa: BLE001 - localise the failure below, case by case
            for name, case in zip(names, group, strict=True):
                try:
                    results[name] = _run_group([case], solver, max_steps, uncertainty)[0]
                except Exception as exc:  # noqa: BLE001 - an escaped exception is an outcome
                    results[name] = exc
    return results


@lru_cache(maxsize=16)
def _jacobian_fn(model_name: str):
    model = get_model(model_name)

    def jac(u, t, t_out, t_back, d):
        return jax.jacfwd(lambda v: model.predict(v, t, (t_out, t_back), d))(u)

    return jax.jit(jax.vmap(jac, in_axes=(0, None, None, None, 0)))


def gradients_finite(case: HardCase, result: CaseFit) -> bool:
    """True when the model's Jacobian is finite at the truth and at each finite fitted point."""
    ts = case.trials
    jac = _jacobian_fn(ts.model)
    t = jnp.asarray(ts.t)
    points = [np.tile(truth_unconstrained(case), (case.n_trials, 1)), np.stack(result.u)]
    if case.u0 is not None:
        points.append(case.u0)
    ok = True
    for u in points:
        finite = np.all(np.isfinite(u), axis=1)
        if finite.any():
            j = jac(jnp.asarray(u[finite]), t, ts.t_out, ts.t_back,
                    jnp.asarray(ts.direction[finite]))
            ok &= bool(np.all(np.isfinite(np.asarray(j))))
    return ok


#: A posterior is confidently wrong when the truth lies further than this many sd
#: (beyond the case's tolerance) from its median.
POSTERIOR_SDS = 4.0


def _compare(case: HardCase, est: dict, spread: dict, flags: dict, trusted: bool, why_not: str,
             n_spread: float) -> tuple[str, str]:
    """Outcome of estimates ``est`` +- ``n_spread * spread`` against the case's truth."""
    silent = [n for n in est if n not in flags
              and not (np.isfinite(est[n]) and np.isfinite(spread[n]))]
    if trusted and silent:
        return "silent_nan", f"non-finite without flag: {silent}"
    if not trusted:
        return "flagged", why_not
    wrong, flagged = [], []
    for name, (rtol, atol) in case.check.items():
        value, true = est[name], case.truth[name]
        if abs(value - true) <= rtol * abs(true) + atol + n_spread * spread[name]:
            continue
        if name in flags:
            flagged.append(f"{name} ({flags[name]})")
        else:
            wrong.append(f"{name}={value:.4g} (truth {true:.4g})")
    if wrong:
        return "confident_wrong", "; ".join(wrong)
    if flagged:
        return "flagged", "; ".join(flagged)
    return "correct", ""


def _fit_verdict(case: HardCase, result: CaseFit, i: int) -> tuple[str, str]:
    status = Status(int(result.status[i]))
    return _compare(case, result.values[i], result.stderr[i], result.flags[i],
                    status is Status.CONVERGED, status.name.lower(), 0.0)


def _posterior_verdict(case: HardCase, result: CaseFit, i: int) -> tuple[str, str]:
    if result.post_error:
        return "error", result.post_error
    if result.post_median is None:
        return "not_run", ""
    return _compare(case, result.post_median[i], result.post_sd[i], result.flags[i],
                    bool(result.post_converged[i]), "posterior not converged", POSTERIOR_SDS)


def judge(case: HardCase, result: CaseFit | Exception) -> list[TrialOutcome]:
    """One :class:`TrialOutcome` per trial of ``case``; case-wide failures fail every trial."""
    if isinstance(result, Exception):
        msg = f"{type(result).__name__}: {result}"
        return [TrialOutcome(case.name, i, "-", "error", False, msg, "error", False, "")
                for i in range(case.n_trials)]
    case_problems = []
    if case.bit_identical and not all(np.array_equal(u, result.u[0]) for u in result.u):
        case_problems.append("identical trials gave different results")
    if not gradients_finite(case, result):
        case_problems.append("non-finite Jacobian")
    out = []
    for i in range(case.n_trials):
        outcome, detail = _fit_verdict(case, result, i)
        uq, uq_detail = _posterior_verdict(case, result, i)
        passed = outcome in case.accept and not case_problems
        detail = "; ".join([d for d in (detail, *case_problems) if d])
        out.append(TrialOutcome(case.name, i, Status(int(result.status[i])).name.lower(),
                                outcome, passed, detail, uq,
                                uq in (*case.accept, "not_run"), uq_detail))
    return out


def run(*, quick: bool = False, seed: int = 0) -> dict:
    """The hard-case section of the bench report: fit and Laplace outcomes on every case.

    Returns ``{"stage": "hard_cases", "summary": {...}, "cases": [row, ...]}``, one row
    per trial (the fields of :class:`TrialOutcome`).
    """
    cases = hard_cases(seed=seed)
    results = fit_cases(cases, max_steps=100 if quick else 200)
    rows = [o.__dict__ for name, case in cases.items() for o in judge(case, results[name])]
    kinds = ("correct", "flagged", "confident_wrong", "silent_nan", "error")
    summary = {
        "hard_cases_total": len(cases),
        "hard_cases_fit_passed": sum(all(r["passed"] for r in rows if r["case"] == n)
                                     for n in cases),
        "hard_cases_laplace_passed": sum(all(r["laplace_passed"] for r in rows if r["case"] == n)
                                         for n in cases),
        **{f"hard_case_fit_{k}": sum(r["outcome"] == k for r in rows) for k in kinds},
        **{f"hard_case_laplace_{k}": sum(r["laplace"] == k for r in rows) for k in kinds},
    }
    return {"stage": "hard_cases", "summary": summary, "cases": rows}
