"""The batched fit and uncertainty on a Dask cluster: trials partitioned across workers.

For users who outgrow one machine. The trials of a batch are cut into contiguous
chunks, one or more per worker thread; every chunk runs the ordinary
:func:`frictionfit.fit.fit_trials` on a worker (itself batched and vmapped), and
the per-chunk results are concatenated back in trial order;
:func:`posterior_distributed` does the same for
:func:`frictionfit.uncertainty.sample_posterior`.

A trial's result does not depend on the chunk it lands in, so the fit and the
Laplace posterior equal the local ones up to rounding (a different batch shape
can change XLA's vectorisation in the last bit); the jittered starts of
``n_starts > 1`` are seeded per trial, from its own samples. emcee's walkers are
the exception: they are drawn per chunk, so a chunk gets other, equally
distributed draws from the same posterior.

``scheduler`` is a ``distributed.Client`` or a scheduler address
(``"tcp://host:8786"``); a client made from an address is closed afterwards.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from frictionfit._optional import require
from frictionfit.errors import FitError
from frictionfit.fit import FitResult, Trials, fit_trials
from frictionfit.fit.result import concat_results, take_trials
from frictionfit.fit.trials import as_trials

__all__ = ["concat_results", "fit_distributed", "map_chunks", "partition", "posterior_distributed",
           "take_trials"]


def partition(n_trials: int, n_chunks: int, groups=None) -> list[slice]:
    """Contiguous, nearly equal slices covering ``range(n_trials)`` (no empty ones).

    With ``groups`` (one label per trial, each group contiguous), a cut never
    splits a group, so tied parameters see their whole group.

    Examples
    --------
    >>> partition(5, 2)
    [slice(0, 3, None), slice(3, 5, None)]
    >>> partition(5, 2, groups=["a", "a", "a", "a", "b"])
    [slice(0, 4, None), slice(4, 5, None)]
    """
    if n_trials < 1 or n_chunks < 1:
        raise FitError(f"cannot partition {n_trials} trials into {n_chunks} chunks")
    cuts = np.linspace(0, n_trials, min(n_chunks, n_trials) + 1).round().astype(int)
    if groups is not None:
        groups = np.asarray(groups)
        starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
        if starts.size != np.unique(groups).size:
            raise FitError("groups must be contiguous to be distributed: sort the trials by "
                           "group first")
        allowed = np.r_[starts, n_trials]
        cuts = np.unique(allowed[np.searchsorted(allowed, cuts)])  # snap each cut forward
    return [slice(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]


def _connect(scheduler):
    """``(client, owned)``: the given Client, or a new one on the address (owned, to close)."""
    Client = require("distributed", "A fit on a Dask cluster").Client
    if isinstance(scheduler, Client):
        return scheduler, False
    if not isinstance(scheduler, str):
        raise FitError(f"scheduler must be a distributed.Client or an address, not {scheduler!r}")
    try:
        return Client(scheduler, timeout="5s"), True
    except OSError as exc:
        raise FitError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from exc


def _rows(value, rows: slice):
    """The trials ``rows`` of a per-trial argument: an array's rows, a :class:`Trials`' trials."""
    if value is None:
        return None
    return value.take(rows) if isinstance(value, Trials) else value[rows]


def map_chunks(func: Callable[..., Any], per_trial: dict[str, np.ndarray | Trials | None],
               shared: dict[str, Any], *, scheduler, n_chunks: int | None = None) -> list[Any]:
    """Run ``func(**chunk_of_per_trial, **shared)`` on the cluster, one task per chunk.

    Parameters
    ----------
    func : callable
        An importable function (workers unpickle it by name).
    per_trial : dict of str -> array (n_trials, ...), Trials or None
        Arguments cut along their first axis (a :class:`~frictionfit.fit.Trials` into its
        trials); ``None`` entries are passed as ``None``.
    shared : dict
        Arguments every chunk receives whole.
    scheduler : distributed.Client or str
        The cluster.
    n_chunks : int, optional
        Number of tasks; default, the cluster's total worker threads.

    Returns
    -------
    list
        The chunk results, in trial order.
    """
    client, owned = _connect(scheduler)
    try:
        if n_chunks is None:
            n_chunks = max(sum(client.nthreads().values()), 1)
        first = next(v for v in per_trial.values() if v is not None)
        n_trials = first.n_trials if isinstance(first, Trials) else len(first)
        futures = [
            client.submit(func, **{k: _rows(v, rows) for k, v in per_trial.items()},
                          **shared, pure=False)
            for rows in partition(n_trials, n_chunks, per_trial.get("groups"))
        ]
        return client.gather(futures)
    finally:
        if owned:
            client.close()


def _fit_chunk(trials, u0, groups, *, fit_kwargs):
    # One solver thread per task: the cluster's worker threads already share the cores.
    return fit_trials(trials, u0=u0, groups=groups, **{"threads": 1, **fit_kwargs})


def fit_distributed(
    y,
    t=None,
    drive_input=None,
    *,
    scheduler,
    n_chunks: int | None = None,
    drive: str = "events",
    direction=None,
    u0=None,
    groups=None,
    **fit_kwargs,
) -> FitResult:
    """:func:`frictionfit.fit.fit_trials` with the trials partitioned across a Dask cluster.

    Parameters
    ----------
    y, t, drive_input, drive, direction, u0, groups
        As for :func:`~frictionfit.fit.fit_trials` (force in N, times in s; or ``y`` a
        :class:`~frictionfit.fit.Trials`); with
        ``groups`` (tied parameters) no group is split across chunks.
    scheduler : distributed.Client or str
        A connected client, or the scheduler's address.
    n_chunks : int, optional
        Tasks to cut the batch into; default, the cluster's total worker threads.
    **fit_kwargs
        Passed unchanged to ``fit_trials`` (``model``, ``solver``, ``chunk_size``, ...).

    Returns
    -------
    FitResult
        One row per trial, in input order; ``wall_s`` is the wall time of the whole
        distributed call, s.

    Examples
    --------
    >>> from distributed import Client, LocalCluster  # doctest: +SKIP
    >>> with LocalCluster(n_workers=2, processes=False) as lc, Client(lc) as c:  # doctest: +SKIP
    ...     res = fit_distributed(y, t, (t_out, t_back), scheduler=c, model="stick_slip")
    """
    start = time.perf_counter()
    trials = as_trials(y, t, drive_input, drive=drive, direction=direction)
    n = trials.n_trials
    per_trial = {"trials": trials, "groups": None if groups is None else np.asarray(groups),
                 "u0": None if u0 is None else np.asarray(u0, dtype=np.float64).reshape(n, -1)}
    parts = map_chunks(_fit_chunk, per_trial, {"fit_kwargs": fit_kwargs}, scheduler=scheduler,
                       n_chunks=n_chunks)
    return concat_results(parts, wall_s=time.perf_counter() - start)


def _posterior_chunk(index, trials, *, fit, seed, kwargs):
    from frictionfit.uncertainty import sample_posterior

    return sample_posterior(take_trials(fit, index), trials, seed=seed + int(index[0]),
                            **kwargs)


def posterior_distributed(fit: FitResult, y, t=None, drive_input=None, *, scheduler,
                          n_chunks: int | None = None, seed: int = 0, **kwargs):
    """:func:`frictionfit.uncertainty.sample_posterior` with the trials spread over Dask.

    Parameters
    ----------
    fit, y, t, drive_input, seed
        As for ``sample_posterior`` (force in N, times in s; or ``y`` the fitted
        :class:`~frictionfit.fit.Trials`); chunk ``c`` starting at
        trial ``i`` samples with ``seed + i``.
    scheduler : distributed.Client or str
        A connected client, or the scheduler's address.
    n_chunks : int, optional
        Tasks; default, the cluster's total worker threads.
    **kwargs
        Passed to ``sample_posterior`` (``method``, ``nwalkers``, ``max_steps``, ...);
        ``chains_path`` is refused (one HDF5 file cannot take writes from many workers).

    Returns
    -------
    Posterior
        One entry per trial, in input order. Laplace results equal the local ones
        up to rounding; emcee draws are seeded per chunk, so they are other draws
        from the same posterior.
    """
    if kwargs.get("chains_path") is not None:
        raise FitError("chains_path is not supported on Dask: save chains per chunk locally")
    start = time.perf_counter()
    trials = as_trials(y, t, drive_input)  # sample_posterior takes the fit's signs
    per_trial = {"index": np.arange(trials.n_trials), "trials": trials}
    shared = {"fit": fit, "seed": seed, "kwargs": kwargs}
    parts = map_chunks(_posterior_chunk, per_trial, shared, scheduler=scheduler,
                       n_chunks=n_chunks)
    return concat_results(parts, wall_s=time.perf_counter() - start)
