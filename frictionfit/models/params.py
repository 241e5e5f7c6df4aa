"""Named physical parameters with units and bounds, and their unconstrained coordinates.

Fits run in an unconstrained coordinate ``u`` and report the physical value:
``"identity"`` (offsets), ``"logit"`` (bounded, linear scale) or ``"loglogit"``
(bounded, log scale, for quantities spanning decades such as stiffness or tau).
A parameter may carry a weakly informative Normal prior on its *sampling
coordinate* (the log of a ``loglogit`` value, the value otherwise): the fit
minimises it with the data (a MAP estimate) and the posterior includes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax.numpy as jnp
import numpy as np

__all__ = ["Param"]


@dataclass(frozen=True)
class Param:
    """A model parameter: name, unit, physical bounds, transform, default and meaning."""

    name: str
    unit: str
    lower: float
    upper: float
    default: float
    transform: str = "loglogit"
    doc: str = ""
    #: ``(centre, sd)`` in the unit: median and sd of the natural log for ``loglogit``,
    #: mean and sd of the value otherwise; ``None``: flat over the bounds.
    prior: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.transform not in ("identity", "logit", "loglogit"):
            raise ValueError(f"{self.name}: unknown transform {self.transform!r}")
        if self.transform != "identity" and not self.lower < self.default < self.upper:
            raise ValueError(f"{self.name}: default {self.default} not inside bounds")
        if self.transform == "loglogit" and self.lower <= 0:
            raise ValueError(f"{self.name}: loglogit needs a positive lower bound")
        if self.prior is not None:
            self.check_prior(self.prior)

    @property
    def signed(self) -> bool:
        """Whether the parameter can take either sign (then its size is no test of it)."""
        return self.lower < 0.0

    def check_prior(self, prior: tuple[float, float]) -> tuple[float, float]:
        """``prior`` as floats; ValueError for a centre outside the bounds or sd <= 0."""
        centre, sd = (float(v) for v in prior)
        inside = self.transform == "identity" or self.lower < centre < self.upper
        if not (inside and np.isfinite(centre) and sd > 0 and np.isfinite(sd)):
            raise ValueError(f"{self.name}: prior {prior!r} needs a centre inside "
                             f"({self.lower:g}, {self.upper:g}) {self.unit} and a positive sd")
        return centre, sd

    def prior_in_sampling(self, prior: tuple[float, float]) -> tuple[float, float]:
        """Centre and sd of ``prior`` on the sampling coordinate (log value for ``loglogit``)."""
        centre, sd = self.check_prior(prior)
        return (float(np.log(centre)) if self.transform == "loglogit" else centre), sd

    def to_sampling(self, u):
        """Sampling coordinate of unconstrained ``u``: the log value (``loglogit``), the
        value otherwise, without the clip of :meth:`to_physical` (smooth everywhere)."""
        if self.transform == "identity":
            return u
        xp = jnp if not isinstance(u, (float, np.ndarray, np.generic)) else np
        lo, hi = self.span
        return lo + (hi - lo) * 0.5 * (1.0 + xp.tanh(0.5 * u))  # the logistic, without overflow

    @cached_property
    def span(self) -> tuple[float, float]:
        """The bounds on the sampling coordinate (their logs for ``loglogit``), as floats:
        constants, not operations, in a traced program."""
        if self.transform == "loglogit":
            return float(np.log(self.lower)), float(np.log(self.upper))
        return float(self.lower), float(self.upper)

    def to_physical(self, u):
        """Physical value (in ``unit``) of unconstrained ``u``; works on JAX and NumPy arrays."""
        if self.transform == "identity":
            return u
        xp = jnp if not isinstance(u, (float, np.ndarray, np.generic)) else np
        v = self.to_sampling(u)
        if self.transform == "loglogit":  # exp(log(upper)) can overshoot by an ulp
            return xp.clip(xp.exp(v), self.lower, self.upper)
        return v

    def to_unconstrained(self, value):
        """Unconstrained ``u`` of a physical value; values on or past a bound are pulled inside."""
        if self.transform == "identity":
            return np.asarray(value, dtype=np.float64)
        lo, hi = self.span
        v = np.log(np.asarray(value, dtype=np.float64)) if self.transform == "loglogit" else value
        frac = np.clip((v - lo) / (hi - lo), 1e-9, 1 - 1e-9)
        return np.log(frac) - np.log1p(-frac)

    def at_bound(self, value, rtol: float = 1e-3) -> np.ndarray:
        """True where ``value`` sits within ``rtol`` (of the transformed span) of a bound."""
        if self.transform == "identity":
            return np.zeros(np.shape(value), dtype=bool)
        lo, hi = self.span
        v = np.log(value) if self.transform == "loglogit" else np.asarray(value)
        frac = (v - lo) / (hi - lo)
        return (frac < rtol) | (frac > 1 - rtol)
