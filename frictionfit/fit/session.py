"""The motor's profile of a session: estimated once from its recordings, held in their fits.

A session's motor moves the same way in every recording: its movement duration and
acceleration share (:data:`SESSION_RIG`) belong to the day, not to a recording, while its
latency after a command goes with the serial link and stays per recording. A
:class:`SessionRig` is that profile, the median over the session's fits with every parameter
free, with the variance of its error for one recording; ``fit_measurements(rig="session")``
estimates one per session of its batch and holds it, and ``rig={session: SessionRig}``
holds profiles estimated before (a recording fitted later in the day, on its own). The held
profile's error is carried into every free parameter's covariance (:func:`held_covariance`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from frictionfit.errors import Status
from frictionfit.fit.result import FitResult
from frictionfit.models import PARAMS, MeasurementModel
from frictionfit.segmentation import robust_sd

__all__ = ["SESSION_RIG", "SessionRig", "estimate_session_rigs", "held_covariance",
           "held_profile", "read_session_rigs", "write_session_rigs"]

#: The rig's parameters a session holds: the movement's duration and acceleration share,
#: set by the motor's profile all day. The latency stays per recording: it jitters from
#: one recording to the next, and holding it would push its error into the stiffness.
SESSION_RIG = ("ramp", "accel")
#: Fewest usable fits a session's profile is taken from.
MIN_RECORDINGS = 2


@dataclass(frozen=True)
class SessionRig:
    """One session's motor profile: ``ramp`` (s) and ``accel`` (share of a movement spent
    accelerating), the medians over ``n_fits`` fits; ``error_cov``: the variance of the held
    values' error for one recording of the session, in the fits' unconstrained coordinates of
    :data:`SESSION_RIG` (the session's spread of values beyond their fits' own variance, a
    robust sd, plus the median's variance)."""

    ramp: float
    accel: float
    error_cov: tuple[tuple[float, ...], ...]
    n_fits: int

    def values(self) -> dict[str, float]:
        """Name -> held value (physical units)."""
        return {"ramp": self.ramp, "accel": self.accel}


def estimate_session_rigs(sessions: Sequence[str], result: FitResult) -> dict[str, SessionRig]:
    """Per session (``sessions``: one per item of ``result``) with at least
    :data:`MIN_RECORDINGS` converged or ill-conditioned fits in ``result`` (fits with every
    parameter of :data:`SESSION_RIG` free), its :class:`SessionRig`."""
    usable = np.isin(result.status, [int(Status.CONVERGED), int(Status.ILL_CONDITIONED)])
    sessions = np.asarray([str(s) for s in sessions])
    u = _rig_u(result)
    rigs = {}
    for s in np.unique(sessions):
        pick = (sessions == s) & usable
        if pick.sum() < MIN_RECORDINGS:
            continue
        centre = np.median(u[pick], axis=0)
        robust_var = robust_sd(u[pick], axis=0) ** 2
        own = np.stack([_block(result, i) for i in np.flatnonzero(pick)])
        fit_var = np.nanmedian(np.diagonal(own, axis1=1, axis2=2), axis=0)
        between = np.clip(robust_var - np.nan_to_num(fit_var), 0.0, None)
        cov = np.diag(between + np.pi / 2 * robust_var / pick.sum())
        ramp, accel = (float(PARAMS[n].to_physical(c)) for n, c in zip(SESSION_RIG, centre,
                                                                         strict=True))
        rigs[str(s)] = SessionRig(ramp, accel, tuple(map(tuple, cov.tolist())),
                                  int(pick.sum()))
    return rigs


def held_profile(sessions: Sequence[str], result: FitResult, rigs: Mapping[str, SessionRig]
                 ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per item of ``result``: the values of :data:`SESSION_RIG` to hold (its session's in
    ``rigs``; its own fit's where its session has none) and their error covariance
    ``(n_items, r, r)`` (the rig's ``error_cov``; its own fit's covariance)."""
    u = _rig_u(result)
    held = {n: PARAMS[n].to_physical(u[:, k]) for k, n in enumerate(SESSION_RIG)}
    error = np.stack([_block(result, i) for i in range(result.n_trials)])
    for i, s in enumerate(sessions):
        rig = rigs.get(str(s))
        if rig is not None:
            for name, value in rig.values().items():
                held[name][i] = value
            error[i] = np.asarray(rig.error_cov)
    return held, error


def held_covariance(model: MeasurementModel, free_fit: FitResult, error: np.ndarray,
                    held: Mapping, rows: np.ndarray | None = None) -> np.ndarray:
    """Per item (of ``rows``), the covariance the held profile adds to ``model``'s free
    parameters (those not in ``held``; unconstrained coordinates): ``B V B^T``, with ``V``
    the held values' error covariance (``error``, :func:`held_profile`) and ``B`` the
    parameters' shift per unit shift of the held ones, ``Sigma_fh Sigma_hh^-1`` in the
    covariance of ``free_fit`` (every parameter free; a parameter its law lacks gets no
    share). Zero where that covariance was not computed."""
    rows = np.arange(free_fit.n_trials) if rows is None else rows
    free = [n for n in model.param_names if n not in held]
    out = np.zeros((len(rows), len(free), len(free)))
    for k, i in enumerate(rows):
        names = free_fit.free_names(i)
        cov = np.asarray(free_fit.cov[i])
        h = [names.index(n) for n in SESSION_RIG]
        if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(error[i]))):
            continue
        cross = np.array([cov[names.index(n), h] if n in names else np.zeros(len(h))
                          for n in free])
        b = np.linalg.lstsq(cov[np.ix_(h, h)], cross.T, rcond=1e-12)[0].T
        out[k] = b @ error[i] @ b.T
    return out


def write_session_rigs(rigs: Mapping[str, SessionRig], path: str | Path) -> None:
    """Write ``rigs`` (session -> :class:`SessionRig`) to a JSON file."""
    Path(path).write_text(json.dumps({s: asdict(r) for s, r in rigs.items()}, indent=2))


def read_session_rigs(path: str | Path) -> dict[str, SessionRig]:
    """The session -> :class:`SessionRig` mapping :func:`write_session_rigs` wrote; a file
    that does not hold one is refused, named."""
    try:
        raw = json.loads(Path(path).read_text())
        return {str(s): SessionRig(float(r["ramp"]), float(r["accel"]),
                                   tuple(tuple(float(x) for x in row) for row in r["error_cov"]),
                                   int(r["n_fits"]))
                for s, r in raw.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a file of session motor profiles "
                         f"({type(exc).__name__}: {exc})") from None


def _rig_u(result: FitResult) -> np.ndarray:
    """Each item's :data:`SESSION_RIG` in its fit's unconstrained coordinates, ``(n, r)``."""
    names = result.member(0).param_names
    return np.stack(result.u)[:, [names.index(n) for n in SESSION_RIG]]


def _block(result: FitResult, i: int) -> np.ndarray:
    """The covariance of :data:`SESSION_RIG` in item ``i``'s fit (its unconstrained
    coordinates; NaN where not computed)."""
    free = result.free_names(i)
    at = [free.index(n) for n in SESSION_RIG]
    return np.asarray(result.cov[i])[np.ix_(at, at)]
