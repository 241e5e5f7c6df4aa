"""Numerical stability: run the hard-case gallery through the fit and judge every trial.

A trial's outcome is one of

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
from frictionfit.fit import FitResult, fit_trials
from frictionfit.models import get_model
from frictionfit.simulation.hard_cases import HardCase, hard_cases, truth_unconstrained

__all__ = ["CaseFit", "TrialOutcome", "fit_cases", "judge", "run"]

#: Trials per vmapped chunk; every group of cases pads to it, so one compile per model.
CHUNK = 16


@dataclass(frozen=True)
class TrialOutcome:
    """The verdict on one trial of one hard case."""

    case: str
    trial: int
    status: str
    outcome: str
    passed: bool
    detail: str


def _groups(cases: Mapping[str, HardCase]) -> dict[tuple, list[str]]:
    """Cases that can share one ``fit_trials`` call: same model, length, dtype, start policy."""
    groups: dict[tuple, list[str]] = {}
    for name, c in cases.items():
        key = (c.model, c.t.size, c.y.dtype.str, c.u0 is not None)
        groups.setdefault(key, []).append(name)
    return groups


def _fit_group(group: list[HardCase], solver: str, max_steps: int) -> FitResult:
    first = group[0]
    y = np.concatenate([c.y for c in group])
    t_out = np.concatenate([np.full(c.n_trials, c.t_out) for c in group])
    t_back = np.concatenate([np.full(c.n_trials, c.t_back) for c in group])
    u0 = None if first.u0 is None else np.concatenate([c.u0 for c in group])
    return fit_trials(y, first.t, (t_out, t_back), model=first.model, solver=solver,
                      max_steps=max_steps, chunk_size=CHUNK, u0=u0)


@dataclass(frozen=True)
class CaseFit:
    """The rows of one case in a batched fit result (only what judging needs)."""

    status: np.ndarray
    values: list[dict]
    stderr: list[dict]
    flags: list[dict]
    u: list[np.ndarray]


def _split(result: CaseFit, sizes: list[int]) -> list[CaseFit]:
    """Per-case rows of a batched result, in order."""
    out, start = [], 0
    for n in sizes:
        rows = slice(start, start + n)
        out.append(CaseFit(np.asarray(result.status)[rows], result.values[rows],
                           result.stderr[rows], result.flags[rows], list(result.u[rows])))
        start += n
    return out


def fit_cases(cases: Mapping[str, HardCase], *, solver: str = "lm",
              max_steps: int = 200) -> dict[str, CaseFit | Exception]:
    """Fit every case, batching compatible cases into one call; an exception is kept, not raised.

    When a batched call raises, its cases are refitted one by one so that the
    exception is pinned on the case that causes it.
    """
    results: dict[str, CaseFit | Exception] = {}
    for names in _groups(cases).values():
        group = [cases[n] for n in names]
        try:
            parts = _split(_fit_group(group, solver, max_steps), [c.n_trials for c in group])
            results.update(zip(names, parts, strict=True))
        except Exception:  # noqa: BLE001 - localise the failure below, case by case
            for name, case in zip(names, group, strict=True):
                try:
                    results[name] = _split(_fit_group([case], solver, max_steps),
                                           [case.n_trials])[0]
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
    jac = _jacobian_fn(case.model)
    t = jnp.asarray(case.t)
    points = [np.tile(truth_unconstrained(case), (case.n_trials, 1)), np.stack(result.u)]
    if case.u0 is not None:
        points.append(case.u0)
    ok = True
    for u in points:
        finite = np.all(np.isfinite(u), axis=1)
        if finite.any():
            j = jac(jnp.asarray(u[finite]), t, case.t_out, case.t_back,
                    jnp.asarray(case.direction[finite]))
            ok &= bool(np.all(np.isfinite(np.asarray(j))))
    return ok


def _verdict(case: HardCase, result: CaseFit, i: int) -> tuple[str, str]:
    status = Status(int(result.status[i]))
    values, errs, flags = result.values[i], result.stderr[i], result.flags[i]
    silent = [n for n in values if n not in flags
              and not (np.isfinite(values[n]) and np.isfinite(errs[n]))]
    if status is Status.CONVERGED and silent:
        return "silent_nan", f"non-finite without flag: {silent}"
    if status is not Status.CONVERGED:
        return "flagged", status.name.lower()
    wrong, flagged = [], []
    for name, (rtol, atol) in case.check.items():
        est, true = values[name], case.truth[name]
        if abs(est - true) <= rtol * abs(true) + atol:
            continue
        if name in flags:
            flagged.append(f"{name} ({flags[name]})")
        else:
            wrong.append(f"{name}={est:.4g} (truth {true:.4g})")
    if wrong:
        return "confident_wrong", "; ".join(wrong)
    if flagged:
        return "flagged", "; ".join(flagged)
    return "correct", ""


def judge(case: HardCase, result: CaseFit | Exception) -> list[TrialOutcome]:
    """One :class:`TrialOutcome` per trial of ``case``; case-wide failures fail every trial."""
    if isinstance(result, Exception):
        msg = f"{type(result).__name__}: {result}"
        return [TrialOutcome(case.name, i, "-", "error", False, msg) for i in range(case.n_trials)]
    case_problems = []
    if case.bit_identical and not all(np.array_equal(u, result.u[0]) for u in result.u):
        case_problems.append("identical trials gave different results")
    if not gradients_finite(case, result):
        case_problems.append("non-finite Jacobian")
    out = []
    for i in range(case.n_trials):
        outcome, detail = _verdict(case, result, i)
        passed = outcome in case.accept and not case_problems
        detail = "; ".join([d for d in (detail, *case_problems) if d])
        out.append(TrialOutcome(case.name, i, Status(int(result.status[i])).name.lower(),
                                outcome, passed, detail))
    return out


def run(*, quick: bool = False, seed: int = 0) -> dict:
    """The hard-case section of the bench report: the fit's outcome on every case.

    Returns ``{"stage": "hard_cases", "summary": {...}, "cases": [row, ...]}``, one row
    per trial with case, status, outcome, passed and detail.
    """
    cases = hard_cases(seed=seed)
    results = fit_cases(cases, max_steps=100 if quick else 200)
    rows = [o.__dict__ for name, case in cases.items() for o in judge(case, results[name])]
    passed = [r["passed"] for r in rows]
    counts = {k: sum(r["outcome"] == k for r in rows)
              for k in ("correct", "flagged", "confident_wrong", "silent_nan", "error")}
    return {"stage": "hard_cases",
            "summary": {"hard_cases_passed": int(sum(
                all(r["passed"] for r in rows if r["case"] == n) for n in cases)),
                "hard_cases_total": len(cases), "hard_case_trials_passed_rate":
                float(np.mean(passed)), **{f"hard_case_{k}": v for k, v in counts.items()}},
            "cases": rows}
