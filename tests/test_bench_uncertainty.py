"""The uncertainty benchmark's quick mode: shape of its report and sane numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from frictionfit.bench.uncertainty import run


@pytest.mark.slow
def test_quick_run_reports_every_summary_key_and_point():
    out = run(quick=True, seed=0)
    json.dumps(out)  # the report writer stores it as JSON
    assert out["stage"] == "uncertainty" and "cpu_count" in out["machine"]
    s = out["summary"]
    for key in ("emcee_s_per_trial", "coverage68_emcee", "coverage95_emcee",
                "coverage68_laplace", "coverage95_laplace", "emcee_converged_rate"):
        assert np.isfinite(s[key]) and s[key] >= 0, key
    for key in ("coverage68_emcee", "coverage95_laplace", "emcee_converged_rate",
                "downstream_accuracy_point", "downstream_accuracy_ivw",
                "downstream_accuracy_with_sd"):
        assert 0.0 <= s[key] <= 1.0, key
    configs = [p["config"] for p in out["points"]]
    assert configs[0] == "laplace" and configs[-1] == "reference"
    assert all(np.isfinite(p["error"]) and np.isfinite(p["sd_error"]) for p in out["points"])
    assert len(s["emcee_s_per_trial_batches"]) == len(s["load_average_during_emcee"])
