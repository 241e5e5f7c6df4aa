"""The nested contact-model family, simplest first; each member adds one physical effect.

1. ``elastic_plastic``: offset, stiffness ``k`` and kinetic friction ``f_kin``
   (plus the drive's nuisance parameters ``delay`` and ``ramp``);
2. ``stick_slip``: + ``f_static_excess`` and ``slip_length`` (static peak above the
   kinetic plateau);
3. ``relaxation``: + one Maxwell branch (``relax_frac``, ``tau``);
4. ``rich``: + a second branch (``relax_frac2``, ``tau2``) and viscous ``damping``.

A model predicts one force channel of one motion: ``offset + direction * F(t)``,
where ``direction`` (+1/-1, which way the channel sees the drive) is fixed from
the data, and the drive's stroke is a nominal ``stroke_mm`` (stiffness is
reported per nominal mm, since stroke and stiffness only appear as a product
until the slider slips).
"""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from frictionfit.models.params import Param
from frictionfit.models.stick_slip import contact_force, drive

__all__ = ["FAMILY", "PARAMS", "ContactModel", "get_model"]

#: Prior of the movement duration ``ramp``: median 0.125 s, sd 0.3 of its log (95 % within
#: 0.07-0.22 s). The rig's motor moves the 1 mm stroke in 100-150 ms (rubbing-lab README;
#: segmentation measured 125-221 ms, p5-p95, on the lab stand-in). Without it the trial's
#: onset only fixes ``k / ramp**2`` and ``slip_length * ramp**2``: a ridge along which the
#: fit wandered (median error of k 60 %, of ramp 39 % on 256 simulated trials; 19 % / 10 %
#: with this prior) and the LM crawled. Override per fit (``priors=``, ``--prior``).
RAMP_PRIOR = (0.125, 0.3)

#: Prior of the slip-weakening length ``slip_length``: median 0.05 (travel unit: mm of a
#: 1 mm stroke), sd 1.5 of its log (95 % within 0.003-1). Below the sample spacing the
#: data no longer see the length: without a prior its posterior is flat in the log down to
#: the bound, and emcee's walkers wander there. In a whole fit, a contact with no static
#: peak has a second optimum without it: a "static excess" that never weakens within the
#: stroke standing in for the kinetic level. Where the force droops over each slide the
#: data outweigh it.
SLIP_PRIOR = (0.05, 1.5)

#: Every parameter of the family, defined once: name, unit, bounds, transform, default.
PARAMS: dict[str, Param] = {
    p.name: p
    for p in (
        Param("offset", "N", -1e6, 1e6, 0.0, "identity", "sensor offset of the channel"),
        Param("k", "N/mm", 1e-3, 1e4, 5.0, "loglogit",
              "tangential stiffness of the contact in series with the finger"),
        Param("f_kin", "N", 1e-5, 1e3, 0.5, "loglogit", "kinetic friction level"),
        Param("delay", "s", 0.0, 0.3, 0.02, "logit", "motor latency after the command"),
        Param("ramp", "s", 0.005, 1.0, 0.12, "loglogit", "duration of the finger movement",
              prior=RAMP_PRIOR),
        Param("f_static_excess", "N", 1e-5, 1e3, 0.1, "loglogit",
              "static minus kinetic friction level"),
        Param("slip_length", "mm", 1e-4, 10.0, 0.05, "loglogit",
              "slip distance over which static friction weakens to kinetic",
              prior=SLIP_PRIOR),
        Param("relax_frac", "1", 0.0, 0.95, 0.3, "logit",
              "fraction of the elastic force that relaxes (Maxwell branch 1)"),
        Param("tau", "s", 1e-4, 100.0, 0.2, "loglogit", "relaxation time of branch 1"),
        Param("relax_frac2", "1", 0.0, 0.95, 0.1, "logit",
              "fraction of the remaining force that relaxes (branch 2)"),
        Param("tau2", "s", 1e-4, 100.0, 2.0, "loglogit", "relaxation time of branch 2"),
        Param("damping", "N s/mm", 1e-7, 10.0, 1e-4, "loglogit", "viscous (bristle) damping"),
        # of the whole-measurement model (frictionfit.models.measurement) only
        Param("drift", "N/s", -1e3, 1e3, 0.0, "identity", "slow linear drift of the channel"),
        Param("leak", "N/mm", -1e3, 1e3, 0.0, "identity",
              "signal proportional to the finger's travel (normal-force leakage)"),
        Param("accel", "1", 0.005, 0.5, 0.1, "logit",
              "share of a movement spent accelerating (and as long braking)"),
        Param("wear", "1/mm", -0.05, 0.05, 0.0, "logit",
              "relative fall of the kinetic level per mm of finger travel (a textile wearing,"
              " or the grip's normal force drifting)", prior=(0.0, 0.05)),
        Param("drag", "N s/mm", 1e-7, 10.0, 1e-3, "loglogit",
              "sliding drag proportional to the finger's velocity"),
    )
}


class NamedParameters:
    """What a model with ``param_names`` and ``prior_table`` properties gets from
    :data:`PARAMS`: the parameters' definitions, their count, physical values from
    unconstrained ones, and the prior rows of the fit."""

    @property
    def params(self) -> tuple[Param, ...]:
        return tuple(PARAMS[n] for n in self.param_names)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def physical(self, u):
        """Physical values (dict name -> array) from unconstrained ``u[..., n_params]``."""
        columns = (u[..., i] for i in range(self.n_params)) if isinstance(u, np.ndarray) \
            else jnp.unstack(u, axis=-1)  # one operation in a traced program, not one per column
        return {p.name: p.to_physical(c) for p, c in zip(self.params, columns, strict=True)}

    def prior_residuals(self, u, sampling: bool = False):
        """``(x_j - centre_j) / sd_j`` per prior, shape ``(..., n_priors)``, where ``x_j`` is
        the sampling coordinate of unconstrained ``u`` (or ``u`` itself if ``sampling``);
        a NumPy array for a NumPy ``u``, else a JAX array."""
        rows = []
        own = dict(zip(self.param_names, self.params, strict=True))
        for name, prior in self.prior_table.items():
            par = own[name]
            centre, sd = par.prior_in_sampling(prior)
            x = u[..., self.param_names.index(name)]
            rows.append(((x if sampling else par.to_sampling(x)) - centre) / sd)
        xp = np if isinstance(u, np.ndarray) else jnp  # NumPy in, NumPy out
        if not rows:
            return xp.zeros((*u.shape[:-1], 0), dtype=u.dtype)
        return xp.stack(rows, axis=-1)


class ContactModel(eqx.Module, NamedParameters):
    """A member of the family: a name, its force-law parameters, and its drive.

    ``drive="events"`` builds the finger displacement from the two ``move``
    command times and fits the motor's ``delay`` and ``ramp`` as nuisance
    parameters; ``drive="given"`` takes a known displacement (mm) per sample
    (e.g. a constant-velocity slide) and adds no parameters. ``priors``:
    ``(name, centre, sd)`` of the Normal priors on the sampling coordinates of
    this member's parameters (see :class:`~frictionfit.models.params.Param`);
    the default is each parameter's own ``prior``.

    Examples
    --------
    >>> m = get_model("stick_slip")
    >>> m.param_names
    ('offset', 'k', 'f_kin', 'f_static_excess', 'slip_length', 'delay', 'ramp')
    >>> m.with_drive("given").param_names[-1]
    'slip_length'
    """

    name: str = eqx.field(static=True)
    law_names: tuple[str, ...] = eqx.field(static=True)
    drive: str = eqx.field(static=True, default="events")
    stroke_mm: float = eqx.field(static=True, default=1.0)
    priors: tuple[tuple[str, float, float], ...] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.drive not in ("events", "given"):
            raise ValueError(f"drive must be 'events' or 'given', not {self.drive!r}")

    def with_drive(self, drive: str, stroke_mm: float = 1.0) -> ContactModel:
        return ContactModel(self.name, self.law_names, drive, stroke_mm, self.priors)

    def with_priors(self, priors: Mapping[str, tuple[float, float] | None] | None = None
                    ) -> ContactModel:
        """This member with each parameter's default prior, updated by ``priors``
        (name -> ``(centre, sd)``, or ``None`` for flat); unknown names raise."""
        table = {p.name: p.prior for p in self.params}
        for name, prior in (priors or {}).items():
            if name not in PARAMS:
                raise ValueError(f"no parameter {name!r} to put a prior on; "
                                 f"parameters are {list(PARAMS)}")
            if name in table:
                table[name] = None if prior is None else PARAMS[name].check_prior(prior)
        chosen = tuple((n, *p) for n, p in table.items() if p is not None)
        return ContactModel(self.name, self.law_names, self.drive, self.stroke_mm, chosen)

    @property
    def prior_table(self) -> dict[str, tuple[float, float]]:
        """Name -> ``(centre, sd)`` of the priors in force (defaults when never set)."""
        if self.priors is None:
            return {p.name: p.prior for p in self.params if p.prior is not None}
        return {n: (c, sd) for n, c, sd in self.priors if n in self.param_names}

    @property
    def param_names(self) -> tuple[str, ...]:
        extra = ("delay", "ramp") if self.drive == "events" else ()
        return ("offset", *self.law_names, *extra)


    def predict(self, u, t, drive_input, direction):
        """Predicted channel (N) at uniform times ``t`` (s) for unconstrained parameters ``u``.

        ``drive_input``: ``(t_out, t_back)``, the ``move`` command times in s, for
        ``drive="events"``; the displacement in mm at each ``t`` for ``drive="given"``.
        ``direction``: +1 or -1, the sign with which the channel sees the force.
        """
        v = self.physical(u)
        if self.drive == "events":
            t_out, t_back = drive_input
            x = drive(t, t_out, t_back, v["delay"], v["ramp"], self.stroke_mm)
        else:
            x = drive_input
        force = contact_force(x, t[1] - t[0], **{n: v[n] for n in self.law_names})
        return v["offset"] + direction * force


_LAWS = {
    "elastic_plastic": ("k", "f_kin"),
    "stick_slip": ("k", "f_kin", "f_static_excess", "slip_length"),
    "relaxation": ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau"),
    "rich": ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
             "relax_frac2", "tau2", "damping"),
}

#: The family, simplest first.
FAMILY: tuple[ContactModel, ...] = tuple(ContactModel(n, laws) for n, laws in _LAWS.items())


def get_model(name: str, drive: str = "events", stroke_mm: float = 1.0,
              priors: Mapping[str, tuple[float, float] | None] | None = None) -> ContactModel:
    """The family member called ``name``, with the given drive and priors (see
    :meth:`ContactModel.with_priors`; ``None``: the parameters' default priors)."""
    for m in FAMILY:
        if m.name == name:
            m = m.with_drive(drive, stroke_mm)
            return m if priors is None else m.with_priors(priors)
    raise ValueError(f"unknown model {name!r}; choose from {[m.name for m in FAMILY]} or 'auto'")
