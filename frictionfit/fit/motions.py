"""Each fitted motion of a whole fit refitted on its own (:func:`refit_motions`): the law on
the motion's window, what belongs to the rig and the sensor held at the whole fit's values;
:meth:`~frictionfit.fit.whole_result.MeasurementFit.per_motion` is its public face."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from frictionfit.fit._whole_batch import (
    UNPOLISHED,
    WHOLE_FIT_SOLVER,
    fit_batch,
    with_solver_tolerances,
)
from frictionfit.fit.result import concat_results
from frictionfit.fit.whole_result import MeasurementFit
from frictionfit.models.measurement import RIG

__all__ = ["MIN_MOTION_BLOCKS", "SETUP", "refit_motions"]

#: Fewest usable blocks for a motion to be refitted on its own (a motion has ~700).
MIN_MOTION_BLOCKS = 100
#: Parameters of the rig and the sensor: held when single motions are refitted.
SETUP = ("offset", "drift", "leak", *RIG)


def _motion_windows(result: MeasurementFit, i: int) -> list[tuple[int, np.ndarray]]:
    """Row ``i``'s motions with enough fitted blocks: ``(motion number, weights)``, the
    weights zero outside the motion's window (from its out command to the next)."""
    d = result.items[i]
    outs = d.commands[d.signs > 0]
    windows = []
    for m, (a, b) in enumerate(zip(outs, [*outs[1:], np.inf], strict=True)):
        weight = np.where((d.t >= a) & (d.t < b), d.weight, 0.0)
        if np.count_nonzero(weight) >= MIN_MOTION_BLOCKS:
            windows.append((m, weight))
    return windows


def refit_motions(result: MeasurementFit, *, max_steps: int = 100, pool_size: int = 16,
                  progress: bool | None = False) -> MeasurementFit:
    """Each fitted motion of each row of ``result`` on its own: the row's law refitted on
    the motion's window, rig and sensor (:data:`SETUP`) and the kinetic level's trend
    (``wear``: one motion cannot tell it from the level) held at the whole fit's values,
    from the whole fit's optimum; the earlier motions are still simulated. Each motion's
    ``f_kin`` is thus its level referred to the whole fit's reference point. Returns one
    row per motion (with fewer than :data:`MIN_MOTION_BLOCKS` blocks: none), with
    ``item_of`` (the row refitted) and ``motion_of`` (the motion's number)."""
    parts = []
    for model in dict.fromkeys(result.fitted_models):
        held = [n for n in (*SETUP, "wear") if n in model.param_names]
        sub, fixed, starts, item_of, motion_of = [], {n: [] for n in held}, [], [], []
        for i in range(result.n_trials):
            if result.member(i) != model:
                continue
            for m, weight in _motion_windows(result, i):
                sub.append(replace(result.items[i], weight=weight))
                starts.append(result.u[i])
                for n in held:
                    fixed[n].append(result.values.at[i, n])
                item_of.append(i)
                motion_of.append(m)
        if sub:
            part = fit_batch(sub, model=model, fix={n: np.array(v) for n, v in fixed.items()},
                             u0=np.stack(starts), max_steps=max_steps, pool_size=pool_size,
                             progress=progress,
                             solver=with_solver_tolerances(WHOLE_FIT_SOLVER, UNPOLISHED))
            part.item_of, part.motion_of = np.array(item_of), np.array(motion_of)
            parts.append(part)
    return concat_results(parts)
