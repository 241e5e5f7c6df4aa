"""Exceptions raised at frictionfit's edges, and the per-trial fit status.

Failures inside a batch are data (a :class:`Status` per trial); failures at the
edges (files, command line, estimators) are exceptions that name the file, the
channel and the problem.
"""

from __future__ import annotations

import enum

__all__ = [
    "AcquisitionError",
    "DatasetError",
    "FitError",
    "FrictionfitError",
    "ModelError",
    "RecordingError",
    "Status",
]


class FrictionfitError(Exception):
    """Base class of every error frictionfit raises on purpose."""


class RecordingError(FrictionfitError, ValueError):
    """A recording file is unreadable or fails validation.

    Attributes
    ----------
    path : str or None
        The file at fault.
    channel : str or None
        The channel at fault, where one is.
    problem : str
        What is wrong, in words.
    """

    def __init__(self, problem: str, *, path: object = None, channel: str | None = None):
        self.path = None if path is None else str(path)
        self.channel = channel
        self.problem = problem
        where = f"{self.path}: " if self.path else ""
        chan = f"channel {channel!r}: " if channel else ""
        super().__init__(f"{where}{chan}{problem}")


class DatasetError(FrictionfitError, ValueError):
    """A dataset folder is missing, empty or inconsistent."""


class ModelError(FrictionfitError, ValueError):
    """A trained-model file is missing, damaged, untrusted or does not fit the data."""

    def __init__(self, problem: str, *, path: object = None):
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


class FitError(FrictionfitError, RuntimeError):
    """A fit could not be set up (bad model name, bad shapes). Per-trial failures are a Status."""


class AcquisitionError(FrictionfitError, IOError):
    """A sensor or actuator did not answer as its protocol says."""


class Status(enum.IntEnum):
    """Outcome of one trial's fit; ``Status.X.message`` says what to try next."""

    CONVERGED = 0
    MAX_STEPS = 1
    NONFINITE = 2
    ILL_CONDITIONED = 3
    INSUFFICIENT_DATA = 4
    AT_BOUND = 5
    SATURATED = 6

    @property
    def message(self) -> str:
        return _STATUS_MESSAGES[self]


_STATUS_MESSAGES = {
    Status.CONVERGED: "The fit converged.",
    Status.MAX_STEPS: (
        "The solver reached max_steps before converging; increase `max_steps`, "
        "or try multi-start (`n_starts`) if the initial guess is poor."
    ),
    Status.NONFINITE: (
        "The residual or its Jacobian became non-finite; check the trial for NaN/inf "
        "samples, saturated channels or extreme offsets."
    ),
    Status.ILL_CONDITIONED: (
        "The fit ended but J^T J is (near) singular: some parameters are not identifiable "
        "from this trial (see the per-parameter flags); consider a smaller model."
    ),
    Status.INSUFFICIENT_DATA: (
        "Too few finite samples to fit this model; the trial is mostly missing or NaN."
    ),
    Status.AT_BOUND: (
        "The stiffness or the kinetic friction ended at a bound of its range: the forces are "
        "not what the law can describe at a plausible scale. Check the channel's unit (forces "
        "in N) and the stroke (--stroke-mm); the values are not measurements."
    ),
    Status.SATURATED: (
        "The channel is saturated (clipped) or stuck: a run of samples sits exactly at its "
        "extreme value. Those samples were left out of the fit, but the force beyond the "
        "clip is unknown, so the peak parameters (f_static_excess) are not determined; "
        "re-record with a larger sensor range or amplifier headroom."
    ),
}
