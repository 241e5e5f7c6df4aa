"""Test catalogue: known-truth trials and the issue's hard cases, small and seeded."""

from __future__ import annotations

import numpy as np

from frictionfit.simulation.trials import TrialSet, simulate_trials

#: Names of the hard cases of issue 3, in the order :func:`hard_cases` returns them.
HARD_CASES = ("never_slips", "near_zero_friction", "very_stiff", "saturated", "pure_noise",
              "missing_30pct", "extreme_offset")


def known_truth(model: str = "elastic_plastic", n: int = 4, seed: int = 0,
                snr_db: float = 30.0) -> TrialSet:
    """A few simulated trials of ``model`` with their truth (single channel, 2 s at 1 kHz)."""
    return simulate_trials(model, n, seed=seed, snr_db=snr_db)


def hard_cases(seed: int = 0) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(t, y, t_out, t_back)``: one elastic-plastic trial per name in :data:`HARD_CASES`."""
    rng = np.random.default_rng(seed)
    sims = [
        simulate_trials("elastic_plastic", 1, seed=seed, params={"k": 6.0, "f_kin": 50.0}),
        simulate_trials("elastic_plastic", 1, seed=seed, params={"f_kin": 1e-4}),
        simulate_trials("elastic_plastic", 1, seed=seed, params={"k": 5e3}),
    ]
    base = simulate_trials("elastic_plastic", 1, seed=seed + 1)
    y0 = base.y[0]
    saturated = np.minimum(y0, np.percentile(y0, 70))
    noise = rng.normal(0.0, 0.1, y0.size)
    missing = y0.copy()
    missing[rng.random(y0.size) < 0.3] = np.nan
    rows = [s.y[0] for s in sims] + [saturated, noise, missing, y0 + 1e4]
    return base.t, np.stack(rows), base.t_out, base.t_back
