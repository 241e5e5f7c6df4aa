"""The uncertainty benchmark's quick mode: shape of its report and sane numbers."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from frictionfit.bench.measurement import KEY_PARAMS
from frictionfit.bench.uncertainty import run
from frictionfit.bench.whole_coverage import _by_param


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
    # the whole-measurement part: 2 measurements with Laplace, 1 with emcee
    assert (s["whole_n"], s["whole_n_emcee"]) == (2, 1)
    cov = s["whole_coverage_by_param"]
    for method in ("laplace", "emcee", "emcee_all_rows"):
        assert {"k", "f_kin"} <= set(cov[method]) <= set(KEY_PARAMS), method
        for param, shares in cov[method].items():
            assert len(shares) == 2 and all(0.0 <= c <= 1.0 for c in shares), (method, param)
    assert 0.0 <= s["whole_emcee_converged_rate"] <= 1.0
    assert np.isfinite(s["whole_emcee_s_per_recording"]) and s["whole_emcee_s_per_recording"] > 0
    assert s["whole_coverage_n_by_param"]["laplace"]["k"] == 2


class _Post(SimpleNamespace):
    def unit(self, i, name):
        return self.units[i].get(name, ("", 1.0))


def test_whole_coverage_counts_what_each_row_fits_in_the_fits_units():
    # quantiles p2.5, p16, median, p84, p97.5; row 1 reports k per mm at 2x its fitted value
    q = {"k": [0.0, 1.0, 2.0, 3.0, 4.0], "f_kin": [0.0, 0.5, 1.0, 1.5, 2.0]}
    post = _Post(method=["laplace", "laplace", "laplace", "none"],
                 converged=np.array([True, False, True, False]),
                 quantiles=[q, {"k": np.array(q["k"]) * 2, "f_kin": q["f_kin"]},
                            {"k": [np.nan] * 5}, q],
                 units=[{}, {"k": ("N/mm", 2.0)}, {}, {}])
    truths = [{"k": 2.0, "f_kin": 1.9},   # k in 68 %, f_kin only in 95 %
              {"k": 3.5},                 # k only in 95 % (7.0 reported / 2); f_kin not fitted
              {"k": 2.0},                 # non-finite posterior: not counted
              {"k": 2.0, "f_kin": 1.0}]   # no posterior: not counted
    shares, counts = _by_param(post, truths, range(4))
    assert shares == {"k": [0.5, 1.0], "f_kin": [0.0, 1.0]}
    assert counts["k"] == 2 and counts["f_kin"] == 1 and counts["tau"] == 0
    shares, counts = _by_param(post, truths, range(4), only_converged=True)
    assert shares == {"k": [1.0, 1.0], "f_kin": [0.0, 1.0]} and counts["k"] == 1
