"""One force channel of a whole rubbing measurement: rig, sensor and material, each fitted once.

A measurement is several back-to-back motions of the same contact. Its parameters
live at three levels, and this model gives each one value per measurement:

- **rig**: the motor's ``delay`` after each ``move`` command, the movement duration
  ``ramp`` and the share ``accel`` of it spent accelerating (and as long braking):
  a trapezoid velocity profile; each movement's own onset and duration around them are
  data (the command times and ``stretch``, which the fit finds movement by movement);
- **sensor**: the channel's ``offset``, its slow ``drift`` (N/s) and a ``leak`` (N per
  mm of finger travel: normal force leaking into the channel as the finger moves);
- **material**: one contact law (:func:`~frictionfit.models.stick_slip.contact_force`)
  driven through the whole measurement, so every stroke starts from the state the
  previous one left, plus a sliding ``drag`` proportional to the finger's velocity; its
  kinetic level changes with the finger's travel by a ``wear`` rate (a textile wearing or
  running in over the strokes of one measurement, or the grip's normal force drifting;
  ``f_kin`` is the level halfway through).

Why not one fit per motion: there, the loading fixes only ``k / ramp**2`` (a ridge) and
the start from rest puts the held force of the previous stroke into the offset. Here the
motor stops at the same time after every command (which fixes ``ramp``), its cruise
speed turns the loading slope into ``k``, and the carried state is simulated.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from functools import lru_cache, partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.models import _pure, _xla
from frictionfit.models._forward import channel_values, timing_normal_equations
from frictionfit.models.family import PARAMS, ContactModel, NamedParameters, get_model
from frictionfit.models.params import Param
from frictionfit.models.stick_slip import contact_force

__all__ = ["HOST_LOOP_COMPILER_OPTIONS", "LAWS", "NAME_PREFIX", "RIG", "MeasurementModel",
           "jit_host_loop", "model_named", "to_unconstrained", "trapezoid"]

#: What a whole-measurement model's name starts with (``measurement-<law>``).
NAME_PREFIX = "measurement-"

#: XLA's options for a program whose work is the compiled loop (its XLA target,
#: :mod:`frictionfit.models._xla`): LLVM's optimisation off. Such a program is the loop's
#: calls and a little algebra around them (the solver's step), so it runs as fast and
#: compiles in about half the time (docs/decisions.md, "Host-loop programs compiled without
#: LLVM's optimisation"). JAX keeps these programs in its persistent cache.
HOST_LOOP_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}


def jit_host_loop(fn: Callable) -> Callable:
    """``jax.jit`` of ``fn``, a program whose work is the compiled loop
    (:data:`HOST_LOOP_COMPILER_OPTIONS`)."""
    return jax.jit(fn, compiler_options=HOST_LOOP_COMPILER_OPTIONS)


#: Contact laws of the measurement model (names of ``contact_force`` arguments): ``no_peak2``
#: has no static peak (the slider slips at its kinetic level), two Maxwell branches.
LAWS: dict[str, tuple[str, ...]] = {
    "no_peak2": ("k", "f_kin", "relax_frac", "tau", "relax_frac2", "tau2", "wear"),
    "relaxation": ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
                   "wear"),
    "relaxation2": ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
                    "relax_frac2", "tau2", "wear"),
    "rich": ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
             "relax_frac2", "tau2", "damping", "wear"),
}


def trapezoid(u, accel):
    """Position (0 to 1) and velocity (per unit ``u``) of a trapezoid-velocity move.

    ``u``: time since the move started over its duration; ``accel``: the share of the
    duration spent accelerating (as long braking), in (0, 0.5). The whole fits' Jacobian
    takes the drive from a compiled twin (:mod:`frictionfit.models._forward`): a change here
    must be made there too.
    """
    v = jnp.clip(u, 0.0, 1.0)
    top = 1.0 / (1.0 - accel)
    rate = top / accel
    head = jnp.minimum(v, accel)
    tail = jnp.clip(v - (1.0 - accel), 0.0, accel)
    pos = (0.5 * rate * head**2 + top * jnp.clip(v - accel, 0.0, 1.0 - 2.0 * accel)
           + top * tail - 0.5 * rate * tail**2)
    inside = (u > 0.0) & (u < 1.0)
    vel = jnp.where(inside, jnp.minimum(top, rate * jnp.minimum(v, 1.0 - v)), 0.0)
    return pos, vel


class MeasurementModel(eqx.Module, NamedParameters):
    """One channel of a whole measurement: ``offset + drift t + leak x + direction F``.

    ``law``: a key of :data:`LAWS`. ``stroke_mm``: the nominal travel of a movement
    (stiffness is reported per nominal mm). ``priors``: ``(name, centre, sd)`` on the
    sampling coordinates, as for :class:`~frictionfit.models.ContactModel` (default: each
    parameter's own prior).
    """

    law: str = eqx.field(static=True, default="relaxation2")
    stroke_mm: float = eqx.field(static=True, default=1.0)
    priors: tuple[tuple[str, float, float], ...] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.law not in LAWS:
            raise ValueError(f"unknown law {self.law!r}; choose from {list(LAWS)}")

    @property
    def name(self) -> str:
        return f"{NAME_PREFIX}{self.law}"

    @property
    def law_names(self) -> tuple[str, ...]:
        return LAWS[self.law]

    @property
    def param_names(self) -> tuple[str, ...]:
        return ("offset", "drift", "leak", *self.law_names, "drag", "delay", "ramp", "accel")

    @property
    def params(self) -> tuple[Param, ...]:
        """The parameters' definitions (:data:`PARAMS`), ``slip_length`` bounded by the
        stroke (:func:`_peak_within_stroke`)."""
        return tuple(_peak_within_stroke(self.stroke_mm) if n == "slip_length" else PARAMS[n]
                     for n in self.param_names)

    def with_priors(self, priors: Mapping[str, tuple[float, float] | None] | None = None
                    ) -> MeasurementModel:
        """This model with the default priors updated by ``priors`` (``None``: flat)."""
        own = dict(zip(self.param_names, self.params, strict=True))
        table = {n: p.prior for n, p in own.items()}
        for name, prior in (priors or {}).items():
            if name not in table:
                raise ValueError(f"no parameter {name!r} to put a prior on; "
                                 f"parameters are {list(self.param_names)}")
            table[name] = None if prior is None else own[name].check_prior(prior)
        chosen = tuple((n, *p) for n, p in table.items() if p is not None)
        return MeasurementModel(self.law, self.stroke_mm, chosen)

    @property
    def prior_table(self) -> dict[str, tuple[float, float]]:
        """Name -> ``(centre, sd)`` of the priors in force (default: each parameter's own)."""
        if self.priors is None:
            return {p.name: p.prior for p in self.params if p.prior is not None}
        return {n: (c, sd) for n, c, sd in self.priors}

    def finger(self, u, t, commands, signs, stretch=None):
        """Finger travel (mm) and velocity (mm/s) at times ``t`` (s).

        ``commands``: the ``move`` command times (s, increasing); ``signs``: +1 for a move
        out, -1 for a move back, 0 for padding; ``stretch``: each movement's duration over
        ``ramp`` (default: 1 for all). Each movement ends before the next command (as in
        the rubbing protocol), so at any time at most the last one commanded is under way
        and only that one is evaluated.
        """
        v = self.physical(u)
        return _travel(self.stroke_mm, v["delay"], v["ramp"], v["accel"], t, commands, signs,
                       _ones_if_none(stretch, commands))

    def _theta(self, u):
        """The physical values of unconstrained ``u (..., p)`` along its last axis in
        :attr:`param_names`' order (NumPy for a NumPy ``u``)."""
        v = self.physical(u)
        xp = np if isinstance(u, np.ndarray) else jnp
        return xp.stack([v[n] for n in self.param_names], axis=-1)

    def channel(self, u: np.ndarray, t: np.ndarray, commands: np.ndarray, signs: np.ndarray,
                stretch: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """:meth:`predict` (N) at unconstrained ``u (..., p)`` for a batch, NumPy in and out,
        by the compiled loop (no JAX; JAX's scan where ``FRICTIONFIT_NATIVE=0``); ``u``
        broadcast over ``t``'s leading axes."""
        theta = self._theta(np.asarray(u, dtype=np.float64))
        theta = np.broadcast_to(theta, (*np.shape(t)[:-1], theta.shape[-1]))
        if not _xla.native_requested():
            return _pure.channel_values(_channel_fn(self.law, self.stroke_mm, None), theta, t,
                                        commands, signs, stretch, direction)
        return channel_values(theta, t, commands, signs, stretch, direction,
                              names=self.law_names, stroke_mm=self.stroke_mm)

    def weighted_cost(self, u: np.ndarray, t: np.ndarray, commands: np.ndarray,
                      signs: np.ndarray, stretch: np.ndarray, direction: np.ndarray,
                      y: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """``|weight (predict - y)|^2 / 2`` (N^2) at unconstrained ``u (..., p)`` for a batch
        (NumPy in and out, by the compiled loop, no JAX: a sampler's density)."""
        value = self.channel(u, t, commands, signs, stretch, direction)
        return 0.5 * np.sum((weight * (value - y)) ** 2, axis=-1)

    def predict(self, u, t, commands, signs, direction, held: tuple[str, ...] = (),
                stretch=None, timing_derivatives: bool = False):
        """Predicted channel (N) at increasing times ``t`` (s, uniform or not), simulated
        from rest at ``t[0]``. ``held``: names of parameters a fit holds fixed: their
        derivative is taken as 0 (a held rig stays out of the contact's Jacobian).
        ``stretch``: as for :meth:`finger`. ``timing_derivatives``: differentiable in
        ``commands`` and ``stretch`` too (otherwise data), every input pushed through the
        simulation (slower; to find each movement's timing)."""
        theta = self._theta(u)
        varied = (None if timing_derivatives
                  else tuple(j for j, n in enumerate(self.param_names) if n not in held))
        return _channel_fn(self.law, self.stroke_mm, varied)(
            theta, t, commands, signs, _ones_if_none(stretch, commands), direction)

    def normal_equations(self, u, t, commands, signs, direction, y, weight,
                         free: tuple[int, ...], stretch=None):
        """``(|r|^2 / 2, J^T J, J^T r)`` of the weighted residual ``r = weight (predict -
        y)`` in the ``free`` entries of unconstrained ``u``: :meth:`predict`'s Jacobian
        taken whole by the compiled loop, its products on the host, so no ``(n, p)``
        Jacobian passes through JAX (the whole fits' step; ``jacfwd`` of JAX's scan off the
        CPU, or where the loop's XLA target is off). Not differentiable."""
        free = tuple(int(j) for j in free)
        return _xla.on_cpu(partial(self._native_normal, free=free),
                           partial(_pure.normal_equations, self._theta,
                                   _channel_fn(self.law, self.stroke_mm, None), free=free))(
            u, t, commands, signs, _ones_if_none(stretch, commands), direction, y, weight)

    def _native_normal(self, u, t, commands, signs, stretch, direction, y, weight,
                       free: tuple[int, ...]):
        """:meth:`normal_equations` by the compiled loop's XLA target."""
        theta = self._theta(u)
        d_theta = jax.jacfwd(self._theta)(u)[:, jnp.asarray(free)]  # du[free] -> dtheta
        rig = any(self.param_names[j] in RIG for j in free)
        cost, ctc, ctr = _xla.normal_equations(
            theta, t, commands, signs, stretch, direction, y, weight,
            names=self.law_names, stroke_mm=self.stroke_mm, rig_columns=rig)
        return cost, d_theta.T @ ctc @ d_theta, d_theta.T @ ctr

    def timing_normal_equations(self, u, t, commands, signs, stretch, direction, y, weight
                                ) -> tuple[float, np.ndarray, np.ndarray]:
        """``(|r|^2 / 2, J^T J, J^T r)`` of the weighted residual ``r = weight (predict - y)``
        of one channel in each movement's onset shift (s) then log duration factor, at zero
        (NumPy in and out, by the compiled loop, or JAX's scan where
        ``FRICTIONFIT_NATIVE=0``; the movement timing's steps)."""
        theta = self._theta(np.asarray(u, dtype=np.float64))  # NumPy: no JAX dispatch
        if not _xla.native_requested():
            return _pure.timing_normal_equations(_channel_fn(self.law, self.stroke_mm, None),
                                                 theta, t, commands, signs, stretch, direction,
                                                 y, weight)
        return timing_normal_equations(theta, t, commands, signs, stretch, direction, y, weight,
                                       names=self.law_names, stroke_mm=self.stroke_mm)


#: The rig's parameters (the motor's timing), the last of :attr:`MeasurementModel.param_names`.
RIG = ("delay", "ramp", "accel")

#: The sensor's parameters, the first of :attr:`MeasurementModel.param_names`.
SENSOR = ("offset", "drift", "leak")


@lru_cache(maxsize=8)
def _peak_within_stroke(stroke_mm: float) -> Param:
    """``slip_length`` at most one stroke (mm): a static peak weakens within the stroke that
    breaks it loose. A longer "weakening" is a level drooping over each slide, which would
    take the kinetic level's place."""
    return replace(PARAMS["slip_length"], upper=stroke_mm)


def model_named(name: str) -> MeasurementModel | ContactModel:
    """The model a result row names (default stroke and priors): a whole-measurement model
    (``measurement-<law>``) or a member of the per-stroke family."""
    if name.startswith(NAME_PREFIX):
        return MeasurementModel(name.removeprefix(NAME_PREFIX))
    return get_model(name)


def _ones_if_none(stretch, commands):
    """Each movement's duration over ``ramp``: ``stretch``, or 1 for every command."""
    return jnp.ones_like(commands) if stretch is None else stretch


def _travel(stroke_mm, delay, ramp, accel, t, commands, signs, stretch):
    """Finger travel (mm) and velocity (mm/s): :meth:`MeasurementModel.finger` in physical
    values."""
    # -1: before the first; comparing with every command is 5x faster than the default
    last = jnp.searchsorted(commands, t, side="right", method="compare_all") - 1
    now = jnp.maximum(last, 0)
    sign = jnp.where(last >= 0, signs[now], 0.0)
    done = jnp.concatenate([jnp.zeros(1, dtype=signs.dtype), jnp.cumsum(signs)])[now]
    duration = ramp * stretch[now]
    pos, vel = trapezoid((t - commands[now] - delay) / duration, accel)
    return stroke_mm * (done + sign * pos), stroke_mm / duration * sign * vel


def _intervals(t):
    """Each sample's interval since the previous one (s), the first as the second."""
    return jnp.diff(t, prepend=2.0 * t[0] - t[1])


@lru_cache(maxsize=32)
def _channel_fn(law: str, stroke_mm: float, varied: tuple[int, ...] | None):
    """``channel(theta, t, commands, signs, stretch, direction)`` (N): the channel with
    ``theta`` the physical parameters in :attr:`MeasurementModel.param_names`' order.

    Its derivative is the channel's Jacobian in the ``varied`` entries of ``theta`` times
    their tangent, the Jacobian from the compiled loop of :mod:`frictionfit.models._forward`
    (the scan's ``jacfwd`` is bound by XLA's kernel launches); its value comes from that
    loop too (faster than XLA's scan even batched), both through its XLA target
    (:mod:`frictionfit.models._xla`; off the CPU, or where that target is off, JAX's scan
    with the held entries' derivative stopped). A Jacobian of the whole
    residual (``jacfwd``) then evaluates the drive and the simulation once, whatever its
    number of parameters, and a held rig leaves the drive's tangents out of the contact.
    ``t``, ``commands``, ``signs``, ``stretch`` and ``direction`` are data: never
    differentiated. ``varied=None``: the plain channel, differentiable in every input.
    """
    names = LAWS[law]
    m, s = len(names), len(SENSOR)

    def channel(theta, t, commands, signs, stretch, direction):
        offset, drift, leak = theta[:s]
        x, speed = _travel(stroke_mm, *theta[-len(RIG):], t, commands, signs, stretch)
        force = contact_force(x, _intervals(t), **dict(zip(names, theta[s:s + m], strict=True)))
        force = force + theta[s + m] * speed
        return offset + drift * (t - t[0]) + leak * x + direction * force

    if varied is None:
        return channel

    mask = np.isin(np.arange(s + m + 1 + len(RIG)), varied)
    pure = partial(_pure.held_channel, channel, mask=tuple(mask.tolist()))
    with_jacobian = partial(_xla.jacobian, names=names, stroke_mm=stroke_mm,
                            rig_columns=any(j >= s + m + 1 for j in varied))
    values = partial(_xla.values, names=names, stroke_mm=stroke_mm)

    simulated = jax.custom_jvp(values)

    @simulated.defjvp
    def _(primals, tangents):
        value, columns = with_jacobian(*primals)
        return value, columns @ jnp.where(mask, tangents[0], 0.0)

    return _xla.on_cpu(simulated, pure)


def to_unconstrained(model: MeasurementModel, values: Mapping[str, float]) -> np.ndarray:
    """Unconstrained vector of ``model`` from physical ``values`` (defaults where absent)."""
    return np.array([p.to_unconstrained(values.get(p.name, p.default)) for p in model.params])
