"""emcee ensembles of many trials advanced in lockstep, with a tau-based stopping rule.

Each trial has its own :class:`emcee.EnsembleSampler` (``vectorize=True``) in its
own thread. Their log-probability functions hand the walkers to a shared
:class:`_Lockstep` gatherer, which evaluates the walkers of *every* running
trial in one batched JAX call once all of them have asked (threads only wait;
the JAX call releases the GIL). A trial stops when its chain is at least
``min_tau_multiple`` integrated autocorrelation times long and tau changed by
less than ``tau_rtol`` since the previous check, or at ``max_steps`` (then it is
flagged ``converged=False``).

Moves (default): an *adaptive independence sampler*, in the sampling coordinates
of :mod:`~frictionfit.uncertainty._logpost` (log units).

1. Walkers start as independent draws from the Laplace t (df 5); three pilot stages
   of ``pilot_steps`` independence-MH steps each refit the proposal to the draws so
   far (the first third of stage 1 dropped): a :class:`~._proposal.RidgeMap` (a
   quadratic, volume-preserving map that straightens the curved ridge) and a t in
   the straightened coordinates, mixed 0.8 / 0.2 with the Laplace t (defensive).
2. The kept chain: 0.8 independence MH from that proposal + 0.2 random walk in the
   straightened coordinates (unsticks walkers in the tails). If the chain has not
   converged at 100 and 200 steps and its largest tau exceeds :data:`REFIT_MIN_TAU`,
   the proposal is refitted on every draw so far and the chain restarted (those
   steps count as pilot, ``ChainResult.n_pilot``).

Why, measured on the default ``relaxation`` model (9 parameters; 2-s, 1 kHz, 20 dB
trials, seed 0, fitted from the truth): the old mix (0.6 independence from the
Laplace t + 0.3 DE + 0.1 DE-snooker, in ``u``; 36 walkers, 2000 steps) had max tau
45-187 steps on 8 of 8 trials, always on ``k``, ``slip_length`` and ``ramp``. Their
posterior is a long, thin ridge: correlations 0.99, ``k ~ ramp**(1.6..2.0)`` and
``slip_length ~ ramp**-(1.7..2.0)`` (the trial's onset fixes ``k / ramp**2``), the
ratio of its thinnest to its longest sd ~1/6000, flat-topped along the ridge with
a cliff on one side, ``ramp`` spanning 0.06-0.5 s (95 %) on some trials. The
logistic map of ``u`` bends that ridge, so DE and stretch moves crawl. Pure
independence MH from the Laplace t in log coordinates: acceptance 0.31 / 0.43,
max tau 10 / 4.5 on two trials; the adaptive sampler: 4 of 8 trials converged
(>= 50 tau) after 225-400 kept steps (max tau 3.6-6.7, acceptance 0.49-0.58); the
other 4 did not in 2000 steps (max tau 54-92: walkers stuck far out on the ridge,
where the fitted proposal is thin). The linear-Gaussian test problem converges
with it in a few hundred steps.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass

import emcee
import numpy as np
from scipy import stats

from frictionfit.uncertainty._proposal import (
    MappedT,
    TMixture,
    independence_move,
    ridge_walk_move,
)

#: A chain not converged at a refit point is refitted and restarted only if its largest
#: tau (steps) exceeds this: at tau 10 the 50-tau rule needs 500 steps, which a better
#: proposal can shorten; at tau ~3.5 (median on 200 relaxation trials) 175 steps will do.
REFIT_MIN_TAU = 10.0

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
    n_pilot : int
        Adaptation steps run before the chain (not part of it; 0 without adaptation).
    """

    samples: np.ndarray
    tau: np.ndarray
    n_steps: int
    burn: int
    thin: int
    acceptance: float
    converged: bool
    n_pilot: int = 0

    def ess(self) -> np.ndarray:
        """Effective sample size per parameter: kept draws x thin / tau."""
        n = self.samples.shape[0] * self.samples.shape[1] * self.thin
        return n / np.maximum(self.tau, 1.0)


def _imh_stage(log_prob, state, nwalkers, proposal, steps):
    """Independence MH from ``proposal`` for ``steps`` steps; the chain and its acceptance."""
    sampler = emcee.EnsembleSampler(nwalkers, state.coords.shape[1], log_prob, vectorize=True,
                                    moves=[independence_move(proposal)])
    state = sampler.run_mcmc(state, steps, progress=False, skip_initial_state_check=True)
    return state, sampler.get_chain(), float(np.mean(sampler.acceptance_fraction))


def _sample_one(slot, lockstep, mean, cov, nwalkers, moves, seed, max_steps, check_every,
                min_tau_multiple, tau_rtol, min_acceptance, backend, pilot_steps,
                pilot_stages, refit_at=(100, 200)) -> ChainResult:
    n_pilot = 0
    try:
        rng = np.random.RandomState(seed)
        log_prob = lockstep.log_prob(slot)
        p = mean.size
        if moves is None:  # adaptive independence sampler (module docstring)
            laplace_t = TMixture.gaussian_t(mean, cov, df=5.0)
            proposal = laplace_t
            state = emcee.State(laplace_t.rvs(nwalkers, rng), random_state=rng.get_state())
            draws = []
            for stage in range(pilot_stages):
                state, chain, _ = _imh_stage(log_prob, state, nwalkers, proposal, pilot_steps)
                draws.append(chain[pilot_steps // 3:] if stage == 0 else chain)
                proposal = MappedT.fit(np.concatenate(draws).reshape(-1, p), laplace_t)
                n_pilot += pilot_steps
            moves = [(independence_move(proposal), 0.8), (ridge_walk_move(proposal), 0.2)]
        else:
            sd = np.sqrt(np.maximum(np.diag(cov), 1e-12))
            p0 = mean + 1e-3 * sd * rng.standard_normal((nwalkers, p))
            state = emcee.State(p0, random_state=rng.get_state())
            draws = None
        refits = list(refit_at) if draws is not None else []
        while True:
            sampler = emcee.EnsembleSampler(nwalkers, p, log_prob, vectorize=True,
                                            moves=moves, backend=backend)
            if backend is not None:
                backend.reset(nwalkers, p)
            tau_old = np.full(p, np.inf)
            converged = refit = False
            while sampler.iteration < max_steps and not converged and not refit:
                state = sampler.run_mcmc(state, min(check_every, max_steps - sampler.iteration),
                                         progress=False, skip_initial_state_check=True)
                tau = sampler.get_autocorr_time(tol=0)
                stable = np.all(np.abs(tau_old - tau) < tau_rtol * tau)
                converged = bool(np.all(np.isfinite(tau)) and stable
                                 and sampler.iteration >= min_tau_multiple * tau.max())
                tau_old = tau
                # Refit and restart only a chain that mixes slowly: one with a small tau
                # converges sooner by running on than by starting over.
                refit = bool(not converged and refits and sampler.iteration >= refits[0]
                             and np.nanmax(tau) > REFIT_MIN_TAU)
            if not refit:
                break
            # Not converged yet: refit the proposal on every draw so far, restart the chain.
            refits.pop(0)
            chain = sampler.get_chain()
            draws.append(chain[chain.shape[0] // 3:])
            proposal = MappedT.fit(np.concatenate(draws).reshape(-1, p), laplace_t)
            moves = [(independence_move(proposal), 0.8), (ridge_walk_move(proposal), 0.2)]
            n_pilot += sampler.iteration
    finally:
        lockstep.done()
    acceptance = float(np.mean(sampler.acceptance_fraction))
    tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else float(sampler.iteration)
    burn = int(np.ceil(2 * tau_max))
    thin = max(1, int(0.5 * np.nanmin(tau))) if np.all(np.isfinite(tau)) else 1
    samples = sampler.get_chain(discard=min(burn, sampler.iteration - 1), thin=thin)
    return ChainResult(samples, tau, sampler.iteration, burn, thin, acceptance,
                       converged and acceptance >= min_acceptance, n_pilot)


def run_lockstep(
    evaluate: Callable[[np.ndarray, np.ndarray], np.ndarray],
    means: np.ndarray,
    covs: np.ndarray,
    *,
    nwalkers: int,
    seed: int = 0,
    max_steps: int = 3000,
    check_every: int = 25,
    min_tau_multiple: float = 50.0,
    tau_rtol: float = 0.05,
    min_acceptance: float = 0.1,
    moves: Callable[[np.ndarray, np.ndarray], list] | None = None,
    backends: list | None = None,
    pilot_steps: int = 30,
    pilot_stages: int = 3,
) -> list[ChainResult]:
    """Sample every trial's posterior with emcee, all trials in lockstep.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(U (R, p), idx (R,)) -> log-posterior (R,)``: row ``r`` is a
        walker of trial ``idx[r]``; called once per lockstep round.
    means, covs : ndarray (n_trials, p), (n_trials, p, p)
        Laplace mode and covariance per trial (in the coordinates ``evaluate``
        takes): the adaptive sampler starts from their t; with ``moves`` given, the
        walkers start in a tight ball (1e-3 sd) at the mode.
    nwalkers : int
        Walkers per trial (at least ``2 p``).
    max_steps, check_every : int
        Step cap per trial; steps between convergence checks.
    min_tau_multiple, tau_rtol, min_acceptance : float
        Convergence: steps >= ``min_tau_multiple`` x max tau, relative tau change
        below ``tau_rtol``, mean acceptance fraction >= ``min_acceptance``.
    moves : callable, optional
        ``moves(mean, cov) -> emcee moves`` (e.g. :func:`default_moves`, the former
        default) instead of the adaptive independence sampler (no pilot).
    backends : list, optional
        One emcee backend per trial (e.g. ``emcee.backends.HDFBackend``).
    pilot_steps, pilot_stages : int
        Adaptation: steps per pilot stage and number of stages.
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
    results: list[ChainResult | BaseException | None] = [None] * n_trials

    def work(i: int) -> None:
        try:
            results[i] = _sample_one(
                i, lockstep, means[i], covs[i], nwalkers,
                None if moves is None else moves(means[i], covs[i]), seed + i, max_steps,
                check_every, min_tau_multiple, tau_rtol, min_acceptance,
                None if backends is None else backends[i], pilot_steps, pilot_stages)
        except Exception as exc:  # reported per trial by the caller
            results[i] = exc

    threads = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(n_trials)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return results
