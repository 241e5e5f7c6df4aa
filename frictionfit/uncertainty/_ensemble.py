"""emcee ensembles of many trials advanced in lockstep, with a tau-based stopping rule.

Each trial has its own :class:`emcee.EnsembleSampler` (``vectorize=True``) in its
own thread. Their log-probability functions hand the walkers to a shared
:class:`_Lockstep` gatherer, which evaluates the walkers of *every* running
trial in one batched JAX call once all of them have asked (threads only wait;
the JAX call releases the GIL). A trial stops when its chain is at least
``min_tau_multiple`` integrated autocorrelation times long and tau changed by
less than ``tau_rtol`` since the previous check, or at ``max_steps`` (then it is
flagged ``converged=False``).

Moves, measured on the default ``relaxation`` model (9 parameters; 2-s, 1 kHz,
20 dB trials; 20 walkers; same 4 trials, 2000 steps each; max tau over parameters,
in steps; machine heavily loaded):

=============================  ===================  ==========
moves                          max tau per trial    acceptance
=============================  ===================  ==========
StretchMove                    117, 152, 162, 178   0.33-0.41
DEMove 0.8 + DESnooker 0.2     69, 93, 110, 134     0.21-0.27
default_moves (see below)      68, 81, 93, 133      0.11-0.27
=============================  ===================  ==========

(wall time for the 4 x 2000 steps: 500 s, 760 s, 513 s). None reaches 50 tau in
2000 steps there: ``k``, ``slip_length`` and ``ramp`` are weakly identified,
their posteriors long and curved. On a Gaussian posterior (the linear-Gaussian
test problem, 5 parameters, 12 walkers, 4 trials) the independence share wins
clearly: max tau 2.5-3.9 (converged after 300-450 steps) against 14-17 for
DE + snooker (700-850 steps) and 56-67 for the stretch move (not converged in
3000). Hence the default: 0.6 independence + 0.3 DE + 0.1 DE-snooker.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass

import emcee
import numpy as np
from scipy import stats

__all__ = ["ChainResult", "IndependenceMove", "SerialHDFBackend", "default_moves",
           "run_lockstep"]


def IndependenceMove(mean: np.ndarray, cov: np.ndarray, df: float = 5.0) -> emcee.moves.MHMove:
    """Independence Metropolis-Hastings from a multivariate t around the Laplace mode.

    Exact for any target (the proposal ratio enters the acceptance); nearly
    independent draws where the posterior is close to its Laplace Gaussian, and
    the t tails (``df``) keep it safe where the posterior is wider.
    """
    dist = stats.multivariate_t(loc=mean, shape=cov, df=df, allow_singular=True)

    def propose(coords: np.ndarray, random: np.random.RandomState):
        new = np.atleast_2d(dist.rvs(size=coords.shape[0], random_state=random))
        return new, dist.logpdf(coords) - dist.logpdf(new)

    return emcee.moves.MHMove(propose)


def default_moves(mean: np.ndarray, cov: np.ndarray) -> list:
    """The move mix: independence proposals from the Laplace t, plus DE moves.

    The DE / DE-snooker share lets the ensemble adapt where the posterior is
    not Gaussian (the independence move alone then sticks).
    """
    return [(IndependenceMove(mean, cov), 0.6), (emcee.moves.DEMove(), 0.3),
            (emcee.moves.DESnookerMove(), 0.1)]


class SerialHDFBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend with every file access serialised, so that the samplers of
    many trials (threads) can save their chains to groups of one file."""

    _lock = threading.RLock()

    @contextlib.contextmanager
    def open(self, mode: str = "r"):
        with self._lock:
            f = super().open(mode)
            try:
                yield f
            finally:
                f.close()


class _Lockstep:
    """Gathers the walkers every running sampler asks for into one evaluation."""

    def __init__(self, evaluate: Callable[[dict[int, np.ndarray]], dict[int, np.ndarray]],
                 n_active: int):
        self._evaluate = evaluate
        self._cond = threading.Condition()
        self._active = n_active
        self._pending: dict[int, np.ndarray] = {}
        self._results: dict[int, object] = {}

    def log_prob(self, slot: int) -> Callable[[np.ndarray], np.ndarray]:
        def log_prob(coords: np.ndarray) -> np.ndarray:
            with self._cond:
                self._pending[slot] = np.asarray(coords, dtype=np.float64)
                self._run_if_ready()
                while slot not in self._results:
                    self._cond.wait()
                out = self._results.pop(slot)
            if isinstance(out, BaseException):
                raise out
            return out

        return log_prob

    def done(self) -> None:
        with self._cond:
            self._active -= 1
            self._run_if_ready()

    def _run_if_ready(self) -> None:
        if not self._pending or len(self._pending) < self._active:
            return
        batch, self._pending = self._pending, {}
        try:
            self._results.update(self._evaluate(batch))
        except Exception as exc:  # every waiting sampler sees the error, none hangs
            self._results.update(dict.fromkeys(batch, exc))
        self._cond.notify_all()


@dataclass
class ChainResult:
    """One trial's converged (or not) chain, unconstrained coordinates.

    Attributes
    ----------
    samples : ndarray (n_kept, n_walkers, n_params)
        Post-burn-in, thinned chain.
    tau : ndarray (n_params,)
        Integrated autocorrelation time per parameter, steps.
    n_steps, burn, thin : int
        Steps run; burn-in discarded and thinning applied (from tau).
    acceptance : float
        Mean acceptance fraction over walkers.
    converged : bool
        Chain >= ``min_tau_multiple`` tau, tau stable, acceptance in range.
    """

    samples: np.ndarray
    tau: np.ndarray
    n_steps: int
    burn: int
    thin: int
    acceptance: float
    converged: bool

    def ess(self) -> np.ndarray:
        """Effective sample size per parameter: kept draws x thin / tau."""
        n = self.samples.shape[0] * self.samples.shape[1] * self.thin
        return n / np.maximum(self.tau, 1.0)


def _sample_one(slot, lockstep, mean, cov, nwalkers, moves, seed, max_steps, check_every,
                min_tau_multiple, tau_rtol, min_acceptance, backend) -> ChainResult:
    try:
        rng = np.random.RandomState(seed)
        sd = np.sqrt(np.maximum(np.diag(cov), 1e-12))
        p0 = mean + 1e-3 * sd * rng.standard_normal((nwalkers, mean.size))
        sampler = emcee.EnsembleSampler(nwalkers, mean.size, lockstep.log_prob(slot),
                                        vectorize=True, moves=moves, backend=backend)
        state = emcee.State(p0, random_state=rng.get_state())
        tau_old = np.full(mean.size, np.inf)
        converged = False
        while sampler.iteration < max_steps and not converged:
            state = sampler.run_mcmc(state, min(check_every, max_steps - sampler.iteration),
                                     progress=False)
            tau = sampler.get_autocorr_time(tol=0)
            stable = np.all(np.abs(tau_old - tau) < tau_rtol * tau)
            converged = bool(np.all(np.isfinite(tau)) and stable
                             and sampler.iteration >= min_tau_multiple * tau.max())
            tau_old = tau
    finally:
        lockstep.done()
    acceptance = float(np.mean(sampler.acceptance_fraction))
    tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else float(sampler.iteration)
    burn = int(np.ceil(2 * tau_max))
    thin = max(1, int(0.5 * np.nanmin(tau))) if np.all(np.isfinite(tau)) else 1
    samples = sampler.get_chain(discard=min(burn, sampler.iteration - 1), thin=thin)
    return ChainResult(samples, tau, sampler.iteration, burn, thin, acceptance,
                       converged and acceptance >= min_acceptance)


def run_lockstep(
    evaluate: Callable[[np.ndarray, np.ndarray], np.ndarray],
    means: np.ndarray,
    covs: np.ndarray,
    *,
    nwalkers: int,
    seed: int = 0,
    max_steps: int = 3000,
    check_every: int = 50,
    min_tau_multiple: float = 50.0,
    tau_rtol: float = 0.05,
    min_acceptance: float = 0.1,
    moves: Callable[[np.ndarray, np.ndarray], list] | None = None,
    backends: list | None = None,
) -> list[ChainResult]:
    """Sample every trial's posterior with emcee, all trials in lockstep.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(U (R, p), idx (R,)) -> log-posterior (R,)``: row ``r`` is a
        walker of trial ``idx[r]``; called once per lockstep round.
    means, covs : ndarray (n_trials, p), (n_trials, p, p)
        Laplace mode and covariance per trial (unconstrained): the walkers start
        in a tight ball (1e-3 sd) at the mode; the default moves use them.
    nwalkers : int
        Walkers per trial (at least ``2 p``).
    max_steps, check_every : int
        Step cap per trial; steps between convergence checks.
    min_tau_multiple, tau_rtol, min_acceptance : float
        Convergence: steps >= ``min_tau_multiple`` x max tau, relative tau change
        below ``tau_rtol``, mean acceptance fraction >= ``min_acceptance``.
    moves : callable, optional
        ``moves(mean, cov) -> emcee moves``; :func:`default_moves` by default.
    backends : list, optional
        One emcee backend per trial (e.g. ``emcee.backends.HDFBackend``).
    """
    n_trials = means.shape[0]

    def gather(batch: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        slots = list(batch)
        U = np.concatenate([batch[s] for s in slots])
        idx = np.concatenate([np.full(len(batch[s]), s) for s in slots])
        out = evaluate(U, idx)
        splits = np.cumsum([len(batch[s]) for s in slots])[:-1]
        return dict(zip(slots, np.split(out, splits), strict=True))

    lockstep = _Lockstep(gather, n_trials)
    make_moves = moves or default_moves
    results: list[ChainResult | BaseException | None] = [None] * n_trials

    def work(i: int) -> None:
        try:
            results[i] = _sample_one(
                i, lockstep, means[i], covs[i], nwalkers, make_moves(means[i], covs[i]),
                seed + i, max_steps, check_every, min_tau_multiple, tau_rtol, min_acceptance,
                None if backends is None else backends[i])
        except Exception as exc:  # reported per trial by the caller
            results[i] = exc

    threads = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(n_trials)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return results
