# ---
# jupyter:
#   frictionfit:
#     quotes_one_run: true
#   jupytext:
#     formats: ipynb,py:percent
#     notebook_metadata_filter: frictionfit
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 05 — Speed against error: how to choose the fit settings
#
# **Question:** how much accuracy does each fit setting buy per second of computing, and
# which settings should a user pick for their data?
#
# The full benchmark (`frictionfit bench all --out DIR`) takes about an hour; its
# `bench.json` can be read here by setting the environment variable
# `FRICTIONFIT_BENCH_JSON` to its path. Without it, this notebook runs the fit stage in
# quick mode plus a tiny grid of settings (16 simulated `relaxation` trials with known
# truth), so its numbers are small-sample and machine-dependent: read the shape of the
# trade-off, not the decimals.

# %%
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from IPython.display import Image, display

from frictionfit.bench import fit as bench_fit
from frictionfit.bench.report import merge, write_report
from frictionfit.bench.timing import machine_info, timed
from frictionfit.errors import Status
from frictionfit.fit import fit_trials
from frictionfit.simulation.trials import simulate_trials

BENCH_JSON = os.environ.get("FRICTIONFIT_BENCH_JSON")
OUT = Path(tempfile.mkdtemp(prefix="frictionfit-nb05-"))

# %% [markdown]
# ## A tiny grid of settings
# Each point: one configuration of `fit_trials` on the same 16 trials, timed after a
# compile call (`frictionfit.bench.timing.timed`), error = median over trials and the
# identifiable parameters of `|estimate - truth| / max(|truth|, 0.05)` (the benchmark's
# definition), counting only converged fits.

# %%
def settings_stage(n: int = 16, seed: int = 0) -> dict:
    """Speed/error points of a few ``fit_trials`` settings on ``n`` relaxation trials."""
    ts = simulate_trials("relaxation", n, seed=seed)
    grid = {"relaxation (default)": {}, "relaxation ftol=1e-3": dict(ftol=1e-3),
            "relaxation max_steps=15": dict(max_steps=15),
            "elastic_plastic (too small)": dict(model="elastic_plastic")}
    points = []
    for config, options in grid.items():
        options = {"model": "relaxation", **options}

        def call(options=options):
            return fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), direction=ts.direction,
                              **options)

        timed(call)  # compile
        seconds, res = timed(call)
        ok = res.status == Status.CONVERGED
        errors = [abs(res.values[p][i] - ts.truth[p][i]) / max(abs(ts.truth[p][i]), 0.05)
                  for i in np.flatnonzero(ok) for p in bench_fit.IDENTIFIABLE
                  if p in res.values and p in ts.truth]  # one law: its parameters
        points.append({"config": config, "seconds_per_trial": seconds / n,
                       "error": float(np.median(errors)) if errors else float("nan"),
                       "error_name": "median rel. param error",
                       "success_rate": float(ok.mean())})
    return {"stage": "settings", "summary": {"settings_trials": n}, "points": points,
            "machine": machine_info()}


if BENCH_JSON:
    bench = json.loads(Path(BENCH_JSON).read_text())
    print("read", BENCH_JSON, "made by:", bench.get("command"))
else:
    quick_s, quick = timed(lambda: bench_fit.run(quick=True, seed=0))
    grid_s, grid = timed(settings_stage)
    print(f"quick fit stage {quick_s:.0f} s, settings grid {grid_s:.0f} s (compiles included)")
    bench = merge([quick, grid],
                  command="notebooks/05_speed_vs_error (quick fit stage + settings grid)")
paths = write_report(bench, OUT)
print("load average:", os.getloadavg())

# %% [markdown]
# ## The Pareto plot
# Time per trial (log axis) against error, one panel per stage; the red line joins the
# configurations that no other one beats on both speed and error at once.

# %%
display(Image(filename=paths["plot"]))

# %%
rows = [{"stage": name, **{k: p.get(k) for k in ("config", "seconds_per_trial", "error",
                                                   "success_rate", "pareto")}}
        for name, stage in bench["stages"].items() for p in stage.get("points", [])]
points = pd.DataFrame(rows)
points.sort_values(["stage", "seconds_per_trial"]).round(5)

# %%
summary = bench["summary"]
print({k: summary.get(k) for k in ("trials_per_s", "speedup_vs_scipy_numpy",
                                   "speedup_vs_scipy_jax", "median_rel_error",
                                   "scipy_median_rel_error", "compile_s")})

# %% [markdown]
# ## How to choose settings
# - **Batch the trials.** The batched LM pays off with many trials per call (pools of up
#   to `chunk_size`): fit all motions and channels of a dataset in one call. With the 4
#   trials of the quick stage it is no faster than scipy driven by JAX (see the summary);
#   the full benchmark measures the large batches. The first call compiles (`compile_s`),
#   later calls with the same shapes and options reuse it; every change of a tolerance
#   or step budget compiles again.
# - **Pick the model you need.** A member too small for the data is fast but biased
#   (`elastic_plastic` on relaxation trials above); `model="auto"` fits every member to
#   choose by BIC, so once a dataset's member is known, name it.
# - **Tolerances and steps.** Loosen `ftol` while the error stays where you need it; cut
#   `max_steps` only while the success rate stays at 1 (a fit that runs out of steps is
#   not CONVERGED and its values are not to be trusted).
#
# ## What we learned
# On this machine (heavily loaded, one timing per point, 16 trials, so only the ordering
# is meaningful), `ftol=1e-3` fitted the relaxation trials about 3x faster than the default
# (0.07 against 0.23 s per trial) at the same error (1.0 % against 1.1 %), while
# `max_steps=15` converged only half of them and the too-small `elastic_plastic` was
# fastest but six times less accurate (6.4 %). In the quick stage (4 trials) frictionfit
# was 15x faster than scipy on a NumPy model but not faster than scipy on the JAX model
# (0.8x): at a handful of trials, batching has nothing to win.
