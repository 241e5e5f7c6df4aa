"""How the batched fit scales: with the number of trials, the trial length, and on Dask.

- Trials: wall time for 10, 100, 1000 and 10000 trials (2 s at 1 kHz), after one
  compile; the log-log slope of seconds against trials for >= 100 trials is the
  ``scaling_exponent`` (1 = linear; below 1, better than linear).
- Length: seconds per trial for 0.5-20 s trials (compile timed apart, per shape).
- Memory: the process's peak resident set size so far (``resource.ru_maxrss``)
  after each size; sizes run in increasing order, so each row bounds that size.
- Dask: the same batch in one process and on a local 2-worker cluster, timed
  alternately (:func:`frictionfit.bench.timing.alternate`).
"""

from __future__ import annotations

import os
import resource
import sys

import numpy as np

from frictionfit._optional import require
from frictionfit.bench.timing import alternate, machine_info, timed
from frictionfit.distributed import fit_distributed
from frictionfit.fit import fit_trials
from frictionfit.simulation.trials import simulate_trials

__all__ = ["dask_speedup", "run"]

#: The family member timed: the default scene (stick-slip + one relaxation branch).
MODEL = "relaxation"


def _max_rss_mb() -> float:
    """Peak resident set size of this process so far, MB (ru_maxrss is KiB on Linux)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024 if sys.platform == "darwin" else 1024)


def _trials(n: int, seed: int, duration_s: float = 2.0):
    return simulate_trials(MODEL, n, seed=seed, duration_s=duration_s, t_out=0.05,
                           t_back=0.05 + duration_s / 2)


def _fit(ts) -> object:
    return fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model=MODEL)


def scale_trials(counts: tuple[int, ...], seed: int = 0) -> list[dict]:
    """Wall time (s) and peak RSS (MB) of one fit per trial count, after a warm-up compile."""
    compile_s, _ = timed(lambda: _fit(_trials(counts[0], seed)))
    rows = []
    for n in counts:
        ts = _trials(n, seed + n)
        seconds, _ = timed(lambda ts=ts: _fit(ts))
        rows.append({"trials": n, "seconds": seconds, "max_rss_mb": _max_rss_mb(),
                     "warmup_compile_s": compile_s})
    return rows


def scale_length(durations: tuple[float, ...], n_trials: int, seed: int = 0) -> list[dict]:
    """Seconds per trial against trial length (s); compile (first call per shape) apart."""
    rows = []
    for d in durations:
        ts = _trials(n_trials, seed, duration_s=d)
        compile_s, _ = timed(lambda ts=ts: _fit(ts))
        seconds, _ = timed(lambda ts=ts: _fit(ts))
        rows.append({"duration_s": d, "trials": n_trials, "seconds_per_trial": seconds / n_trials,
                     "first_call_s": compile_s})
    return rows


def exponent(rows: list[dict], min_trials: int = 100) -> float:
    """Log-log slope of seconds against trials over the rows with ``trials >= min_trials``."""
    pts = [(r["trials"], r["seconds"]) for r in rows if r["trials"] >= min_trials]
    if len(pts) < 2:
        pts = [(r["trials"], r["seconds"]) for r in rows]
    n, s = np.log(np.array(pts, dtype=np.float64)).T
    return float(np.polyfit(n, s, 1)[0])


def dask_speedup(n_trials: int = 256, repeats: int = 3, seed: int = 0, scheduler=None) -> dict:
    """Speed-up of the fit on a Dask cluster over one process, same trials, timed alternately.

    ``scheduler``: an existing cluster (Client or address) instead of a new
    ``LocalCluster(n_workers=2, threads_per_worker=1, processes=False)``; the
    summary's ``workers`` says how many workers the ratio was measured with.
    """
    distributed = require("distributed", "The Dask speed-up")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster

    ts = _trials(n_trials, seed)
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                           dashboard_address=":0") if scheduler is None else None
    client = scheduler if isinstance(scheduler, Client) else Client(cluster or scheduler)
    try:
        timing = alternate({
            "local": lambda: _fit(ts),
            "dask": lambda: fit_distributed(ts.y, ts.t, (ts.t_out, ts.t_back),
                                            scheduler=client, model=MODEL),
        }, repeats=repeats)
        workers = len(client.scheduler_info()["workers"])
    finally:
        if client is not scheduler:
            client.close()
        if cluster is not None:
            cluster.close()
    local_s, dask_s = timing["local"]["median_s"], timing["dask"]["median_s"]
    return {"stage": "dask", "summary": {
        "trials": n_trials, "local_s": local_s, "dask_s": dask_s, "workers": workers,
        "load_average": os.getloadavg()[0], "dask_speedup_2_workers": local_s / dask_s,
        "times_s": {k: v["times_s"] for k, v in timing.items()}}}


def run(*, quick: bool = False, seed: int = 0) -> dict:
    """Scaling with trials and length; ``quick`` stops at 1000 trials and 5-s trials.

    Returns ``{"stage": "scaling", "points": [{"trials", "seconds", "max_rss_mb"}],
    "lengths": [...], "summary": {"scaling": [...], "scaling_exponent": b}, "machine": ...}``.
    """
    counts = (10, 100, 1000) if quick else (10, 100, 1000, 10000)
    points = scale_trials(counts, seed)
    lengths = scale_length((0.5, 2.0, 5.0) if quick else (0.5, 2.0, 5.0, 20.0),
                           8 if quick else 32, seed)
    return {"stage": "scaling", "model": MODEL, "points": points, "lengths": lengths,
            "summary": {"scaling": [{"trials": p["trials"], "seconds": p["seconds"]}
                                    for p in points],
                        "scaling_exponent": exponent(points),
                        "peak_rss_mb": max(p["max_rss_mb"] for p in points),
                        "scaling_load_average": os.getloadavg()[0]},
            "machine": machine_info()}
