"""The rig of a session: its motor's profile and its finger's creep, estimated once from its
recordings and held in their fits.

A session's motor moves the same way in every recording: its movement duration and
acceleration share (:data:`SESSION_RIG`) belong to the day, not to a recording, while its
latency after a command goes with the serial link and stays per recording. A
:class:`SessionRig` is that profile, the median over the session's fits with every parameter
free, with the variance of its error for one recording; ``fit_measurements(rig="session")``
estimates one per session of its batch and holds it, and ``rig={session: SessionRig}``
holds profiles estimated before (a recording fitted later in the day, on its own). A session
is named within its rig (:attr:`~frictionfit.recording.Recording.session`: ``"<rig>/<session>"``
where ``metadata.rig`` is given), so two rigs' days numbered alike are two sessions. The held
profile's error is carried into every free parameter's covariance (:func:`held_covariance`).

The finger's creep (:data:`CREEP`) is the rig's too: the slow relaxation branch's time
constant, longer than a hold, is one per session and channel (:func:`session_creep`), while
its share stays per recording (a creeping finger relaxes a stiff contact more than a soft
one).
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

__all__ = ["CREEP", "SESSION_RIG", "SessionRig", "estimate_session_rigs", "held_covariance",
           "held_profile", "read_session_rigs", "session_creep", "write_session_rigs"]

#: The rig's parameters a session holds: the movement's duration and acceleration share,
#: set by the motor's profile all day. The latency stays per recording: it jitters from
#: one recording to the next, and holding it would push its error into the stiffness.
SESSION_RIG = ("ramp", "accel")
#: The rig's creep a session holds per channel: the slow relaxation branch's time constant.
CREEP = ("tau2",)
#: Fewest usable fits a session's profile (or creep) is taken from.
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
    usable = _usable(result)
    sessions = np.asarray([str(s) for s in sessions])
    u = _rig_u(result)
    rigs = {}
    for s in np.unique(sessions):
        pick = (sessions == s) & usable
        if pick.sum() < MIN_RECORDINGS:
            continue
        own = np.stack([_block(result, i) for i in np.flatnonzero(pick)])
        centre, cov = _centre(u[pick], own)
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
                    held: Mapping, rows: np.ndarray | None = None,
                    names: Sequence[str] = SESSION_RIG) -> np.ndarray:
    """Per item (of ``rows``), the covariance the held profile adds to ``model``'s free
    parameters (those not in ``held``; unconstrained coordinates): ``B V B^T``, with ``V``
    the held values' error covariance (``error``, :func:`held_profile`) and ``B`` the
    parameters' shift per unit shift of the held ones (``names``), ``Sigma_fh Sigma_hh^-1`` in
    the inverse curvature of ``free_fit``'s density (``density_cov`` where it has one, else
    its ``cov``; ``names`` free; a parameter its law lacks gets no share). Zero where that
    covariance was not computed."""
    rows = np.arange(free_fit.n_trials) if rows is None else rows
    free = [n for n in model.param_names if n not in held]
    out = np.zeros((len(rows), len(free), len(free)))
    curvature = getattr(free_fit, "density_cov", None) or free_fit.cov
    for k, i in enumerate(rows):
        cov = np.asarray(curvature[i])
        fitted = free_fit.free_names(i)
        if not (set(names) <= set(fitted) and np.all(np.isfinite(cov))
                and np.all(np.isfinite(error[i]))):
            continue
        h = [fitted.index(n) for n in names]
        cross = np.array([cov[fitted.index(n), h] if n in fitted else np.zeros(len(h))
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


def _rig_u(result: FitResult, names: Sequence[str] = SESSION_RIG) -> np.ndarray:
    """Each item's ``names`` in its fit's unconstrained coordinates, ``(n, r)``."""
    params = result.member(0).param_names
    return np.stack(result.u)[:, [params.index(n) for n in names]]


def _block(result: FitResult, i: int, names: Sequence[str] = SESSION_RIG) -> np.ndarray:
    """The covariance of ``names`` in item ``i``'s fit (its unconstrained coordinates; NaN
    where not computed)."""
    free = result.free_names(i)
    at = [free.index(n) for n in names]
    return np.asarray(result.cov[i])[np.ix_(at, at)]


def _usable(result: FitResult) -> np.ndarray:
    """Fits a session's values are taken from: converged, or ill-conditioned (their values
    stand though some are poorly determined)."""
    return np.isin(result.status, [int(Status.CONVERGED), int(Status.ILL_CONDITIONED)])


def _centre(u: np.ndarray, own: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The median of one session's values ``u`` ``(m, r)`` (unconstrained) and the variance of
    its error for one recording ``(r, r)``: the session's spread beyond the fits' own
    variances (``own``, ``(m, r, r)``), a robust sd, plus the median's variance."""
    robust_var = robust_sd(u, axis=0) ** 2
    fit_var = np.nanmedian(np.diagonal(own, axis1=1, axis2=2), axis=0)
    between = np.clip(robust_var - np.nan_to_num(fit_var), 0.0, None)
    return np.median(u, axis=0), np.diag(between + np.pi / 2 * robust_var / len(u))


def session_creep(sessions: Sequence[str], channels: Sequence[str], result: FitResult
                  ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per item of ``result`` (fits with :data:`CREEP` free; ``sessions`` and ``channels``: one
    per item): the creep to hold, the median over the usable fits of its session and channel
    (its own fit's value where they are fewer than :data:`MIN_RECORDINGS`, or it has no
    session), in physical units; and that value's error variance ``(n, r, r)`` in the fits'
    unconstrained coordinates (its own fit's covariance where it keeps its own)."""
    u = _rig_u(result, CREEP)
    error = np.stack([_block(result, i, CREEP) for i in range(result.n_trials)])
    usable = _usable(result) & np.all(np.isfinite(u), axis=1)
    keys = np.array([f"{s}\0{c}" for s, c in zip(sessions, channels, strict=True)])
    for key in np.unique(keys):
        pick = (keys == key) & usable
        if key.startswith("None\0") or pick.sum() < MIN_RECORDINGS:
            continue
        centre, cov = _centre(u[pick], error[pick])
        u[keys == key], error[keys == key] = centre, cov
    return {n: PARAMS[n].to_physical(u[:, k]) for k, n in enumerate(CREEP)}, error
