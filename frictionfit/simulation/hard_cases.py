"""A named gallery of hard cases for the fit and the uncertainty, with known truth.

Each :class:`HardCase` is a small batch of one-channel trials (1.2 s at 1 kHz)
that stresses one numerical weakness: a contact that
never slips, friction near zero, static = kinetic, a stiffness so high that the
loading takes less than one sample, relaxation faster than a sample or slower
than the recording, 30 % missing samples with NaN bursts, a clipped channel, a
dead channel, pure noise, an offset 1e4 times the signal, a one-sample-long
phase, float32 input, extreme starting points and identical repeated trials.

A case states what a *right* outcome is, as data: ``check`` names the
parameters that must be within tolerance of the truth unless the fit flags them
(or ends with a non-converged status), and ``accept`` says whether a flag or
status is an acceptable answer at all. Judging a fit against a case is the
bench's job (:mod:`frictionfit.bench.hard_cases`); this module only makes data.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.models import PARAMS, get_model
from frictionfit.simulation.trials import TrialSet

__all__ = ["BASE_TRUTH", "CASES", "NOISE_SD", "HardCase", "hard_cases", "truth_unconstrained"]

#: Sensor noise of every case, N (absolute: a weak signal is weak against it).
NOISE_SD = 0.01
#: The nominal stick-slip contact every case perturbs (physical units).
BASE_TRUTH: dict[str, float] = {
    "offset": 0.2, "k": 15.0, "f_kin": 0.8, "f_static_excess": 0.4,
    "slip_length": 0.06, "delay": 0.02, "ramp": 0.12,
    "relax_frac": 0.3, "tau": 0.15,
}
#: Trial length (s) and sample rate (Hz): out at 50 ms, back at 650 ms.
DURATION_S, RATE_HZ = 1.2, 1000.0
_T_OUT, _T_BACK = 0.05, 0.65


@dataclass(frozen=True)
class HardCase:
    """One hard case: trials, the right answer and what counts as right.

    Attributes
    ----------
    name, description : str
        Short identifier and one sentence on what makes it hard.
    trials : TrialSet
        The data and what generated it: ``trials.model`` is the family member to fit
        (also the generating one unless the data have no model), ``trials.y`` the force
        (N; float32 for the float32 case, NaN where samples are missing), ``trials.truth``
        the generating parameters, ``trials.noise_sd`` :data:`NOISE_SD`.
    truth : dict of str -> float
        The right answer: the true physical value of each parameter of the model (0
        where there is no contact force at all).
    check : dict of str -> (rtol, atol)
        Parameters that must satisfy ``|est - truth| <= rtol |truth| + atol`` unless
        flagged; a converged, unflagged value outside it is a confident wrong answer.
    accept : frozenset of {"correct", "flagged"}
        Acceptable outcomes: right within tolerance, or an explicit status / flag.
    u0 : ndarray (n_trials, n_params) or None
        Unconstrained starting points to force (``None``: the fit's own guess).
    bit_identical : bool
        All trials are identical copies, so their results must be bit-identical.
    """

    name: str
    description: str
    trials: TrialSet
    truth: dict[str, float]
    check: dict[str, tuple[float, float]]
    accept: frozenset[str] = frozenset({"correct", "flagged"})
    u0: np.ndarray | None = None
    bit_identical: bool = False

    @property
    def n_trials(self) -> int:
        return self.trials.n_trials


@lru_cache(maxsize=8)
def _predictor(model_name: str):
    """A jitted batch predictor of ``model_name``; cached so the gallery compiles once per model."""
    model = get_model(model_name)

    def one(u, t, t_out, t_back, direction):
        return model.predict(u, t, (t_out, t_back), direction)

    return jax.jit(jax.vmap(one, in_axes=(0, None, None, None, 0)))


def _simulate(model: str, n: int, seed: int, t_back: float, **changes: float):
    """Trials of ``model`` at the base truth with ``changes``, plus white noise of NOISE_SD."""
    rng = np.random.default_rng(seed)
    names = get_model(model).param_names
    truth = {k: float(changes.get(k, BASE_TRUTH[k])) for k in names}
    t = np.arange(int(DURATION_S * RATE_HZ)) / RATE_HZ
    u = np.tile([PARAMS[k].to_unconstrained(truth[k]) for k in names], (n, 1))
    direction = rng.choice([-1.0, 1.0], n)
    clean = np.asarray(_predictor(model)(jnp.asarray(u), jnp.asarray(t), _T_OUT, t_back,
                                         jnp.asarray(direction)))
    return t, clean + rng.normal(0.0, NOISE_SD, clean.shape), direction, truth


def _case(name, description, model, n, seed, check, *, t_back=_T_BACK, y_map=None,
          accept=("correct", "flagged"), no_contact=None, **changes) -> HardCase:
    """Build a case; ``no_contact`` (the constant level, N) marks data without any contact force."""
    t, y, direction, truth = _simulate(model, n, seed, t_back=t_back, **changes)
    if y_map is not None:
        y = y_map(y, np.random.default_rng(seed + 2), truth, direction)
    trials = TrialSet(model, t, y, _T_OUT, t_back, direction,
                      {k: np.full(n, v) for k, v in truth.items()}, np.full(n, NOISE_SD))
    if no_contact is not None:
        truth = {**truth, "offset": no_contact, "f_kin": 0.0, "f_static_excess": 0.0}
    return HardCase(name, description, trials, truth, check, frozenset(accept))


def _missing(y, rng, truth, direction):
    y = y.copy()
    y[rng.random(y.shape) < 0.3] = np.nan
    for row in y:
        for start in rng.integers(0, y.shape[1] - 60, 3):
            row[start:start + 60] = np.nan
    return y


def _clipped(y, rng, truth, direction):
    # A saturating amplifier: the static peak is cut at the kinetic plateau + 25% of the excess.
    level = truth["f_kin"] + 0.25 * truth["f_static_excess"]
    return np.clip(y, truth["offset"] - level, truth["offset"] + level)


def _dead(y, rng, truth, direction):
    return np.full_like(y, 0.731)  # a stuck ADC reading


def _noise_only(y, rng, truth, direction):
    return rng.normal(0.0, NOISE_SD, y.shape)


def _float32(y, rng, truth, direction):
    return y.astype(np.float32)


def _repeat(y, rng, truth, direction):
    return np.repeat(y[:1], y.shape[0], axis=0)


def _extreme_u0(case: HardCase) -> HardCase:
    params = get_model(case.trials.model).params
    sign = np.where(np.arange(case.n_trials) % 2 == 0, 1.0, -1.0)[:, None]
    u0 = np.where([p.transform == "identity" for p in params], 0.0, 25.0 * sign)
    return replace(case, name="extreme_start", u0=u0,
                   description="every bounded parameter starts at u = +-25 (within 1e-11 "
                               "of a bound, in the transform's span)")


_FRICTION = {"f_kin": (0.05, 0.01), "offset": (0.0, 0.01)}

_BUILDERS: dict[str, Callable[[int], HardCase]] = {
    "nominal": lambda s: _case(
        "nominal", "control: the base stick-slip contact at 40 dB", "stick_slip", 2, s,
        {**_FRICTION, "f_static_excess": (0.05, 0.01)}, accept=("correct",)),
    "never_slips": lambda s: _case(
        "never_slips", "k * stroke (1.5 N) stays below the friction limit: friction unseen",
        "stick_slip", 2, s, {"k": (0.05, 0.0), "f_kin": (0.0, 0.0)}, k=1.5, f_kin=3.0),
    "near_zero_friction": lambda s: _case(
        "near_zero_friction", "two slippery layers: f_kin = 0.02 N, twice the noise",
        "stick_slip", 2, s, {"f_kin": (0.1, 0.005), "offset": (0.0, 0.005)}, f_kin=0.02,
        f_static_excess=0.005),
    "static_equals_kinetic": lambda s: _case(
        "static_equals_kinetic", "no static peak: f_static_excess = 1e-5 N (its lower bound)",
        "stick_slip", 2, s, {**_FRICTION, "f_static_excess": (0.0, 0.05)},
        f_static_excess=1e-5),
    "stiff_sub_sample": lambda s: _case(
        "stiff_sub_sample", "k = 5000 N/mm: the loading takes less than one sample",
        "stick_slip", 2, s, {**_FRICTION, "k": (0.5, 0.0)}, k=5000.0),
    "tau_below_sample": lambda s: _case(
        "tau_below_sample", "relaxation time 0.3 ms, a third of a sample", "relaxation", 2, s,
        {"tau": (0.0, 1e-3), "offset": (0.0, 0.01)}, tau=3e-4),
    "tau_beyond_recording": lambda s: _case(
        "tau_beyond_recording", "relaxation time 50 s, 40 x the recording", "relaxation", 2, s,
        {"tau": (0.5, 0.0), "offset": (0.0, 0.01)}, tau=50.0),
    "missing_30pct": lambda s: _case(
        "missing_30pct", "30% of samples missing at random plus three 60-sample NaN bursts",
        "stick_slip", 2, s, _FRICTION, y_map=_missing),
    "clipped": lambda s: _case(
        "clipped", "saturated channel: clipped just above the kinetic plateau, static peak cut",
        "stick_slip", 2, s, {**_FRICTION, "f_static_excess": (0.1, 0.0)}, y_map=_clipped),
    "dead_channel": lambda s: _case(
        "dead_channel", "a stuck channel: every sample reads 0.731 N", "stick_slip", 2, s,
        {"f_kin": (0.0, 0.0)}, y_map=_dead, accept=("flagged",), no_contact=0.731),
    "pure_noise": lambda s: _case(
        "pure_noise", "no contact at all: white noise of 0.01 N", "stick_slip", 2, s,
        {"f_kin": (0.0, 0.01), "offset": (0.0, 0.005)}, y_map=_noise_only, no_contact=0.0),
    "huge_offset": lambda s: _case(
        "huge_offset", "sensor offset 1e4 N, 1e4 x the friction signal", "stick_slip", 2, s,
        {"f_kin": (0.05, 0.01), "offset": (1e-6, 0.01)}, offset=1e4),
    "one_sample_phase": lambda s: _case(
        "one_sample_phase", "the out phase lasts one sample (t_back = t_out + 1 ms)",
        "stick_slip", 2, s, {"f_kin": (0.0, 0.0), "offset": (0.0, 0.01)}, t_back=_T_OUT + 1e-3),
    "float32_input": lambda s: _case(
        "float32_input", "the force arrives as float32", "stick_slip", 2, s, _FRICTION,
        y_map=_float32, accept=("correct",)),
    "identical_trials": lambda s: replace(_case(
        "identical_trials", "four bit-identical copies of one trial", "stick_slip", 4, s,
        _FRICTION, y_map=_repeat, accept=("correct",)), bit_identical=True),
}
_BUILDERS["extreme_start"] = lambda s: _extreme_u0(_case(
    "extreme_start", "", "stick_slip", 2, s, _FRICTION))
#: The names of the gallery's cases, in order.
CASES: tuple[str, ...] = tuple(_BUILDERS)


def hard_cases(names: list[str] | None = None, seed: int = 0) -> dict[str, HardCase]:
    """The gallery, ``{name: HardCase}``, deterministic given ``seed``.

    Parameters
    ----------
    names : list of str, optional
        A subset of the gallery; all cases when omitted.
    seed : int
        Base seed; each case derives its own from it.

    Examples
    --------
    >>> cases = hard_cases(["pure_noise", "huge_offset"], seed=1)
    >>> cases["huge_offset"].truth["offset"]
    10000.0
    """
    names = list(_BUILDERS) if names is None else names
    unknown = sorted(set(names) - set(_BUILDERS))
    if unknown:
        raise ValueError(f"unknown hard case(s) {unknown}; choose from {sorted(_BUILDERS)}")
    return {n: _BUILDERS[n](seed * 100_000 + zlib.crc32(n.encode()) % 99_991) for n in names}


def truth_unconstrained(case: HardCase) -> np.ndarray:
    """The true parameters of ``case`` in the model's unconstrained coordinates."""
    params = get_model(case.trials.model).params
    return np.array([p.to_unconstrained(np.clip(case.truth[p.name], p.lower, p.upper))
                     for p in params])
