"""Truth recovery and speed of whole-measurement fits on ``frictionfit simulate`` measurements.

Every simulator effect is on (motor profile with per-movement jitter, damping, drag,
cross-talk, drift, AR(1) noise, transmission faults). Errors are relative to the
index channel's truth in each sidecar (median over the fitted motions).
"""

from __future__ import annotations

import time

import numpy as np

from frictionfit.errors import Status
from frictionfit.fit.measurement import fit_measurements, measurement_data
from frictionfit.simulation.materials import CLASSES
from frictionfit.simulation.measurements import simulate_measurements

__all__ = ["KEY_PARAMS", "recovery"]

#: The law parameters whose recovery is scored (the material's physics).
KEY_PARAMS = ("k", "f_kin", "f_static_excess", "relax_frac", "tau")
_SCORED = (*KEY_PARAMS, "slip_length", "drag", "ramp")


def _truth(rec, name: str) -> float:
    motions = rec.truth["motions"][1:]
    if name == "ramp":
        return float(np.median([m["ramp"] for m in motions]))
    if name == "drag":
        return float(np.median([m["params"]["drag"] * abs(m["channels"]["index_x"]["gain"])
                                for m in motions]))
    return float(np.median([m["channels"]["index_x"][name] for m in motions]))


def recovery(n: int = 35, seed: int = 0, channel: str = "index_x") -> dict:
    """Fit ``n`` simulated measurements (classes in turn, sessions 1-2) twice; the second
    call is timed. Returns the summary dict of the ``measurements`` block of ``bench fit``."""
    specs = [(1 + i % 2, CLASSES[(7 * i) % len(CLASSES)], 1 + i // len(CLASSES))
             for i in range(n)]
    recs = simulate_measurements(specs, seed=seed)
    items = [measurement_data(r, channel) for r in recs]
    start = time.perf_counter()
    fit_measurements(items, progress=False)
    first = time.perf_counter() - start
    start = time.perf_counter()
    res = fit_measurements(items, progress=False)
    steady = time.perf_counter() - start
    ok = np.array([Status(int(s)) in (Status.CONVERGED, Status.ILL_CONDITIONED)
                   for s in res.status])
    errors = {name: np.array([v[name] / _truth(r, name) - 1.0
                              for r, v in zip(recs, res.values, strict=True)])
              for name in _SCORED}
    unflagged = np.array([not any(p in f for p in KEY_PARAMS) for f in res.flags])
    return {
        "n_recordings": n, "channel": channel, "law": res.model[0],
        "recordings_per_s": n / steady, "compile_s": max(first - steady, 0.0),
        "median_rel_error_by_param": {k: float(np.median(np.abs(e[ok]))) if ok.any() else None
                                      for k, e in errors.items()},
        "median_signed_error_by_param": {k: float(np.median(e[ok])) if ok.any() else None
                                         for k, e in errors.items()},
        "converged_rate": float(np.mean(res.status == Status.CONVERGED)),
        "converged_unflagged_rate": float(np.mean((res.status == Status.CONVERGED) & unflagged)),
        "flagged_rate_by_param": {k: float(np.mean([k in f for f in res.flags]))
                                  for k in res.values[0]},
    }
