"""emcee for many trials at once: one ensemble of every running trial's walkers.

All running trials share one :class:`emcee.EnsembleSampler` (``vectorize=True``):
rows ``j * w ... (j + 1) * w - 1`` of its ensemble are the ``w`` walkers of the
``j``-th running trial. Its moves are Metropolis-Hastings moves that move each
walker alone, with its own trial's proposal, so walkers of different trials never
interact and each block is an exact MCMC chain of its own trial's posterior; one
log-probability call per step evaluates the walkers of every running trial in one
batched JAX call. Every ``check_every`` steps each trial's chain is checked: a trial
stops when its chain is at least ``min_tau_multiple`` integrated autocorrelation
times long, tau changed by less than ``tau_rtol`` since the previous check and its
walkers agree (rank-normalised split R-hat at most :data:`RHAT_MAX` on every parameter,
after a burn-in of 2 tau), or at ``max_steps`` (then it is flagged ``converged=False``);
its walkers leave the ensemble and the sampler goes on with the rest. The walkers are
independent chains (no move mixes them), so R-hat over them is the standard check: tau
is an average over the walkers and alone does not see one walker stuck.

One ensemble rather than a sampler per trial: every walker of a step is evaluated in one
call, with no thread per trial contending for the GIL.

Moves: an *adaptive independence sampler*, in the sampling coordinates of
:mod:`~frictionfit.uncertainty._logpost` (log units).

1. Walkers start as independent draws from the Laplace t (df 5); ``pilot_stages``
   stages of ``pilot_steps`` independence-MH steps each refit the proposal to the
   draws so far (the first third of stage 1 dropped): a
   :class:`~._proposal.RidgeMap` (a quadratic, volume-preserving map that
   straightens the curved ridge) and a t in the straightened coordinates, mixed
   0.8 / 0.2 with the Laplace t (defensive).
2. The kept chain: 0.8 independence MH from that proposal + 0.2 random walk in the
   straightened coordinates (unsticks walkers in the tails). If the chain has not
   converged at the refit points (``refit_at``: by default 100 steps, then 200, 500 and
   1000 steps after each restart) and its largest tau exceeds :data:`REFIT_MIN_TAU`, the
   proposal is refitted on the draws so far and the chain restarted (those steps count
   as pilot, ``ChainResult.n_pilot``). The later points give a chain whose proposal missed
   a tail or a bend a proposal fitted on a longer chain.

Why an independence sampler and not DE or stretch moves: the posterior is a long, thin,
curved ridge (``k / ramp**2`` fixed by a trial's onset) along which those moves crawl,
and walkers of one trial share only the proposal, never a move. Since each walker is a
chain of its own and R-hat asks each to be long, a trial needs few walkers
(``n_params + 1`` by default in :func:`~frictionfit.uncertainty.sample_posterior`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import emcee
import numpy as np
from scipy.special import ndtri
from scipy.stats import rankdata
from tqdm.auto import tqdm

from frictionfit.uncertainty._proposal import Proposal, Proposals

#: Largest rank-normalised split R-hat over a trial's walkers for a converged chain
#: (Vehtari et al. 2021, arviz's threshold).
RHAT_MAX = 1.01

#: A chain not converged at a refit point is refitted and restarted only if its largest
#: tau (steps) exceeds this: at tau 10 the 50-tau rule needs 500 steps, which a better
#: proposal can shorten; a short tau is left to run.
REFIT_MIN_TAU = 10.0

__all__ = ["RHAT_MAX", "ChainResult", "integrated_time", "run_lockstep", "split_rhat"]


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
        Chain >= ``min_tau_multiple`` tau, tau stable, walkers agreeing (R-hat), acceptance
        in range.
    n_pilot : int
        Adaptation steps run before the chain (not part of it; 0 without adaptation).
    rhat : ndarray (n_params,)
        Rank-normalised split R-hat per parameter over the walkers, after the burn-in
        (:func:`split_rhat`; NaN where not computed).
    """

    samples: np.ndarray
    tau: np.ndarray
    n_steps: int
    burn: int
    thin: int
    acceptance: float
    converged: bool
    n_pilot: int = 0
    rhat: np.ndarray | None = None

    def ess(self) -> np.ndarray:
        """Effective sample size per parameter: kept draws x thin / tau."""
        n = self.samples.shape[0] * self.samples.shape[1] * self.thin
        return n / np.maximum(self.tau, 1.0)


@dataclass
class _Trial:
    """The sampling state of one trial: its proposal and its chain so far."""

    index: int
    proposal: Proposal
    refits: list[int]
    draws: list[np.ndarray] = field(default_factory=list)  # pilot draws (steps, w, p)
    chain: list[np.ndarray] = field(default_factory=list)  # kept chain blocks
    log_prob: list[np.ndarray] = field(default_factory=list)
    accepted: np.ndarray | None = None  # accepted moves per walker, kept chain
    n_pilot: int = 0
    tau: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return sum(len(c) for c in self.chain)

    def refit(self, draws: np.ndarray) -> None:
        """Add ``draws (steps, w, p)`` to the pilot draws and refit the proposal."""
        self.draws.append(draws)
        p = draws.shape[-1]
        self.proposal = Proposal.fit(np.concatenate(self.draws).reshape(-1, p),
                                     self.proposal.laplace)

    def restart(self) -> None:
        """Refit the proposal on the chain so far (its last two thirds) and start anew."""
        chain = np.concatenate(self.chain)
        self.refit(chain[len(chain) // 3:])
        self.n_pilot += len(chain)
        self.chain, self.log_prob, self.accepted, self.tau = [], [], None, None


def _moves(running: list[_Trial], independence: float = 1.0) -> list:
    """emcee moves of the shared ensemble: each walker proposed by its own trial's
    proposal, independence MH with weight ``independence``, else a ridge walk."""
    stacked = Proposals([tr.proposal for tr in running])
    moves = [(emcee.moves.MHMove(stacked.independence), independence)]
    if independence < 1.0:
        moves.append((emcee.moves.MHMove(stacked.ridge_walk), 1.0 - independence))
    return moves


def _run(evaluate, running: list[_Trial], nwalkers: int, moves: list, state: emcee.State,
         steps: int) -> tuple[emcee.State, emcee.EnsembleSampler]:
    """Advance the shared ensemble of ``running`` trials by ``steps`` steps."""
    idx = np.repeat([tr.index for tr in running], nwalkers)
    sampler = emcee.EnsembleSampler(len(running) * nwalkers, state.coords.shape[1],
                                    lambda x: evaluate(x, idx), vectorize=True, moves=moves)
    # A walker still at -inf log-probability whose proposal is -inf too gives
    # -inf - -inf = NaN in emcee's MH step: a rejection, not an error.
    with np.errstate(invalid="ignore"):
        state = sampler.run_mcmc(state, steps, progress=False, skip_initial_state_check=True)
    return state, sampler


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time per parameter (steps) of ``chain (steps, walkers, p)``.

    emcee's estimator (:func:`emcee.autocorr.integrated_time` with ``tol=0``): the
    walkers' normalised autocorrelation functions averaged, summed up to Sokal's
    window (the first lag ``M >= c tau(M)``). Vectorised over walkers and parameters
    (emcee loops over both in Python: a quarter of the sampler's time on 24 trials);
    equal to emcee's to rounding (test). NaN for a walker frozen in place.
    """
    n, _, p = chain.shape
    x = chain - chain.mean(axis=0)
    size = 2 * (1 << (n - 1).bit_length())
    f = np.fft.rfft(x, n=size, axis=0)
    acf = np.fft.irfft(f * np.conj(f), n=size, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        taus = 2.0 * np.cumsum(np.mean(acf / acf[:1], axis=1), axis=0) - 1.0
        inside = np.arange(n)[:, None] < c * taus
    window = np.where(inside.any(axis=0), np.argmin(inside, axis=0), n - 1)
    return taus[window, np.arange(p)]


def split_rhat(chain: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat per parameter of ``chain (steps, walkers, p)``, each
    walker a chain: the larger of the bulk and the folded (tails) R-hat (Vehtari et al.
    2021). Equal to ``arviz.rhat(..., method="rank")`` to rounding; a twin so that the
    sampler's loop does not import arviz, vectorised over the parameters."""
    half = chain.shape[0] // 2
    x = np.concatenate([chain[:half], chain[chain.shape[0] - half:]], axis=1)
    folded = np.abs(x - np.median(x.reshape(-1, x.shape[2]), axis=0))
    return np.maximum(_basic_rhat(_normal_scores(x)), _basic_rhat(_normal_scores(folded)))


def _normal_scores(x: np.ndarray) -> np.ndarray:
    """Normal scores of the pooled ranks (ties averaged) per parameter, Blom's offsets."""
    size = x.shape[0] * x.shape[1]
    ranks = rankdata(x.reshape(size, -1), axis=0).reshape(x.shape)
    return ndtri((ranks - 0.375) / (size + 0.25))


def _basic_rhat(z: np.ndarray) -> np.ndarray:
    """Gelman-Rubin R-hat per parameter of ``z (steps, chains, p)``."""
    n = z.shape[0]
    within = np.mean(np.var(z, axis=0, ddof=1), axis=0)
    between = n * np.var(np.mean(z, axis=0), axis=0, ddof=1)
    return np.sqrt((between / within + n - 1) / n)


def _by_trial(a: np.ndarray, running: list[_Trial], axis: int = 1) -> list[np.ndarray]:
    """The running trials' blocks of an ensemble array (walkers along ``axis``)."""
    return np.split(a, len(running), axis=axis)


def _keep(state: emcee.State, running: list[_Trial], keep: list[int], nwalkers: int):
    """The ensemble state and trial list reduced to the running trials ``keep``."""
    rows = (np.arange(nwalkers) + nwalkers * np.array(keep, dtype=int)[:, None]).ravel()
    return (emcee.State(state.coords[rows], log_prob=state.log_prob[rows],
                        random_state=state.random_state), [running[j] for j in keep])


def _extend(tr: _Trial, chain, log_prob, accepted, max_steps, min_tau_multiple, tau_rtol,
            min_acceptance) -> ChainResult | None:
    """Add a block of steps to a trial's chain; its result when it stops, else None.

    Converged: at least ``min_tau_multiple`` tau, tau within ``tau_rtol`` of the
    previous check, and R-hat over the walkers at most :data:`RHAT_MAX` after a burn-in of
    2 tau (checked last: it ranks the chain). A chain that mixes slowly is refitted and
    restarted at the refit points (only then: one with a small tau converges sooner by
    running on).
    """
    tr.chain.append(chain)
    tr.log_prob.append(log_prob)
    tr.accepted = accepted if tr.accepted is None else tr.accepted + accepted
    tau_old = np.full(chain.shape[-1], np.inf) if tr.tau is None else tr.tau
    full = np.concatenate(tr.chain)
    tr.tau = integrated_time(full)
    stable = np.all(np.abs(tau_old - tr.tau) < tau_rtol * tr.tau)
    long_enough = bool(np.all(np.isfinite(tr.tau)) and stable
                       and tr.n_steps >= min_tau_multiple * tr.tau.max())
    if long_enough or tr.n_steps >= max_steps:
        rhat = _rhat_after_burn(full, tr.tau)
        converged = long_enough and not np.any(rhat > RHAT_MAX)
        if converged or tr.n_steps >= max_steps:
            return _result(tr, full, min_acceptance, converged, rhat)
    if tr.refits and tr.n_steps >= tr.refits[0] and np.any(tr.tau > REFIT_MIN_TAU):
        tr.refits.pop(0)
        tr.restart()
    return None


def _burn(tau: np.ndarray, n_steps: int) -> int:
    """Burn-in (steps): twice the largest tau, the whole chain but one step at most."""
    tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else float(n_steps)
    return min(int(np.ceil(2 * tau_max)), n_steps - 1)


def _rhat_after_burn(chain: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """R-hat per parameter of a kept ``chain`` after its burn-in (NaN under 4 steps, and
    for a parameter no walker moves: a held one)."""
    chain = chain[_burn(tau, len(chain)):]
    if len(chain) < 4:
        return np.full(chain.shape[-1], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):  # a frozen walker: NaN
        return split_rhat(chain)


def _result(tr: _Trial, chain: np.ndarray, min_acceptance: float, converged: bool,
            rhat: np.ndarray) -> ChainResult:
    """The trial's :class:`ChainResult` from its whole kept ``chain``."""
    tau = tr.tau
    acceptance = float(np.mean(tr.accepted) / len(chain))
    finite = np.all(np.isfinite(tau))
    burn = _burn(tau, len(chain))
    thin = max(1, int(0.5 * np.nanmin(tau))) if finite else 1
    samples = chain[burn:][thin - 1::thin]
    return ChainResult(samples, tau, len(chain), burn, thin, acceptance,
                       converged and acceptance >= min_acceptance, tr.n_pilot, rhat)


def _save_chain(backend: emcee.backends.HDFBackend, tr: _Trial) -> None:
    """Write a trial's kept chain to an emcee HDF5 backend (read back with its API)."""
    chain, log_prob = np.concatenate(tr.chain), np.concatenate(tr.log_prob)
    backend.reset(chain.shape[1], chain.shape[2])
    backend.grow(len(chain), None)
    with backend.open("a") as f:
        g = f[backend.name]
        g["chain"][...] = chain
        g["log_prob"][...] = log_prob
        g["accepted"][...] = tr.accepted
        g.attrs["iteration"] = len(chain)


@dataclass(frozen=True)
class _Rules:
    """When a trial's kept chain stops (see :func:`run_lockstep`)."""

    max_steps: int
    check_every: int
    min_tau_multiple: float
    tau_rtol: float
    min_acceptance: float


def _pilot_stage(evaluate, running: list[_Trial], state: emcee.State, results: list,
                 nwalkers: int, pilot_steps: int, stage: int):
    """One adaptation stage: run, refit each trial's proposal; the state and trials left
    (a trial whose refit fails gets its exception in ``results``)."""
    state, sampler = _run(evaluate, running, nwalkers, _moves(running), state, pilot_steps)
    keep = []
    for j, (tr, block) in enumerate(zip(running, _by_trial(sampler.get_chain(), running),
                                        strict=True)):
        try:
            tr.refit(block[pilot_steps // 3:] if stage == 0 else block)
        except Exception as exc:  # this trial's failure, not the batch's
            results[tr.index] = exc
            continue
        tr.n_pilot += pilot_steps
        keep.append(j)
    return _keep(state, running, keep, nwalkers)


def _kept_block(evaluate, running: list[_Trial], state: emcee.State, results: list,
                nwalkers: int, rules: _Rules, backends: list | None):
    """One block of the kept chains; the state and the trials still running (a trial
    that stops gets its ChainResult, or its exception, in ``results``)."""
    steps = min(rules.check_every, min(rules.max_steps - tr.n_steps for tr in running))
    state, sampler = _run(evaluate, running, nwalkers, _moves(running, 0.8), state, steps)
    blocks = zip(running, _by_trial(sampler.get_chain(), running),
                 _by_trial(sampler.get_log_prob(), running),
                 _by_trial(sampler.backend.accepted, running, axis=0), strict=True)
    keep = []
    for j, (tr, chain, log_prob, accepted) in enumerate(blocks):
        try:
            done = _extend(tr, chain, log_prob, accepted, rules.max_steps,
                           rules.min_tau_multiple, rules.tau_rtol, rules.min_acceptance)
            if done is not None and backends is not None:
                _save_chain(backends[tr.index], tr)
        except Exception as exc:  # this trial's failure, not the batch's
            done = exc
        if done is None:
            keep.append(j)
        else:
            results[tr.index] = done
    return _keep(state, running, keep, nwalkers)


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
    backends: list | None = None,
    pilot_steps: int = 30,
    pilot_stages: int = 3,
    refit_at: tuple[int, ...] = (100, 200, 500, 1000),
) -> list[ChainResult | BaseException]:
    """Sample every trial's posterior with emcee, all trials in one shared ensemble.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(U (R, p), idx (R,)) -> log-posterior (R,)``: row ``r`` is a
        walker of trial ``idx[r]``; called once per step for every running trial.
    means, covs : ndarray (n_trials, p), (n_trials, p, p)
        Laplace mode and covariance per trial (in the coordinates ``evaluate``
        takes): the walkers start as draws from their t.
    nwalkers : int
        Walkers per trial.
    max_steps, check_every : int
        Step cap of each trial's kept chain; steps between convergence checks.
    min_tau_multiple, tau_rtol, min_acceptance : float
        Convergence: steps >= ``min_tau_multiple`` x max tau, relative tau change
        below ``tau_rtol``, mean acceptance fraction >= ``min_acceptance``.
    backends : list, optional
        One ``emcee.backends.HDFBackend`` per trial; the kept chain is written there.
    pilot_steps, pilot_stages : int
        Adaptation: steps per pilot stage and number of stages.
    refit_at : tuple of int
        Chain lengths at which a slowly mixing chain is refitted and restarted, each
        counted from the previous restart (their sum adds to a chain's step cap).

    Returns
    -------
    list
        A :class:`ChainResult` per trial, or the exception that stopped the sampler
        (the same one for every trial still running then). Deterministic given
        ``seed`` and the batch; a trial's draws depend on which trials share its batch.
    """
    n, p = means.shape
    rng = np.random.RandomState(seed)
    running = [_Trial(i, Proposal.from_laplace(means[i], covs[i]), list(refit_at))
               for i in range(n)]
    coords = Proposals([tr.proposal for tr in running]).rvs(nwalkers, rng).reshape(-1, p)
    state = emcee.State(coords, random_state=rng.get_state())
    results: list[ChainResult | BaseException | None] = [None] * n
    rules = _Rules(max_steps, check_every, min_tau_multiple, tau_rtol, min_acceptance)
    bar = tqdm(total=n, desc="emcee", unit="trial", leave=False, disable=None)
    try:
        for stage in range(pilot_stages):
            if not running:
                break
            state, running = _pilot_stage(evaluate, running, state, results, nwalkers,
                                          pilot_steps, stage)
        while running:
            state, kept = _kept_block(evaluate, running, state, results, nwalkers, rules,
                                      backends)
            bar.update(len(running) - len(kept))
            running = kept
    except Exception as exc:  # the shared evaluation failed: every running trial reports it
        for tr in running:
            results[tr.index] = exc
    finally:
        bar.close()
    return results
