"""Any optimistix least-squares solver over a batch of problems, in a refilled pool of slots.

:func:`solve_pooled` calls a solver's ``init`` / ``step`` / ``terminate`` under
``vmap`` for a pool of ``B`` slots. One jitted call advances every running slot by
up to ``segment`` steps (a ``lax.while_loop`` that also ends once every slot is
done; a finished slot is held as it is). Between calls the host takes out the slots
whose ``terminate`` said stop, or that used ``max_steps``, and puts waiting problems
in their place, ``init`` re-run for those slots only. So a slow problem never holds
the others back, as it does in a vmapped ``optx.least_squares``, whose while-loop
runs every problem until the slowest finishes. When no problem waits, the pool
shrinks (``B/4``, ``B/16``) around the tail of slow ones.

Only the array part of a solver's state leaves the compiled call (and stays on the
device); the rest (functions, jaxprs, tags) is rebuilt inside each call by tracing
``init``, which costs nothing at run time. Forward-mode Jacobians
(``options={"jac": "fwd"}``: few parameters, thousands of residuals) for the
solvers that take the option. A finished slot's outcome becomes a
:class:`~frictionfit.errors.Status` in one table, :data:`RESULT_STATUS`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from frictionfit.errors import FitError, Status

__all__ = ["RESULT_STATUS", "in_threads", "pool_sizes", "solve_pooled"]

#: What a solver's result means for a trial. A slot that used ``max_steps`` without
#: ``terminate`` saying stop is ``Status.MAX_STEPS``; a result not listed, too.
RESULT_STATUS = (
    (optx.RESULTS.successful, Status.CONVERGED),
    (optx.RESULTS.nonlinear_max_steps_reached, Status.MAX_STEPS),
    (optx.RESULTS.max_steps_reached, Status.MAX_STEPS),
    (optx.RESULTS.nonlinear_divergence, Status.NONFINITE),
    (optx.RESULTS.nonfinite, Status.NONFINITE),
    (optx.RESULTS.nonfinite_input, Status.NONFINITE),
    (optx.RESULTS.singular, Status.ILL_CONDITIONED),
    (optx.RESULTS.breakdown, Status.ILL_CONDITIONED),
    (optx.RESULTS.stagnation, Status.ILL_CONDITIONED),
    (optx.RESULTS.conlim, Status.ILL_CONDITIONED),
)
#: Status code of a slot still running (not a Status).
RUNNING = -1


def _status(result) -> jax.Array:
    """The Status code of one slot's ``optx.RESULTS`` (traced)."""
    code = jnp.array(int(Status.MAX_STEPS))
    for item, status in RESULT_STATUS:
        code = jnp.where(result == item, int(status), code)
    return code


class _Slots(NamedTuple):
    """The pool's carry: every leaf has the slot axis first."""

    y: jax.Array  # (B, p) current point
    state: object  # the array part of the solver's state
    steps: jax.Array  # (B,) steps taken
    stop: jax.Array  # (B,) terminate said stop, or the solver failed
    result: object  # (B,) optx.RESULTS of the last terminate


def _where_slots(keep, old, new):
    """Per slot, ``old`` where ``keep`` else ``new`` (every leaf has the slot axis first)."""
    return jax.tree_util.tree_map(
        lambda a, b: jnp.where(keep.reshape(keep.shape + (1,) * (a.ndim - 1)), a, b), old, new)


@lru_cache(maxsize=32)
def _segment_fn(static_solver, fn: Callable, segment: int, max_steps: int, jac: str,
                compiler_options: tuple[tuple[str, object], ...]):
    """Jitted ``start(arrays, live, y0, args) -> slots`` and ``run(arrays, slots, fresh,
    live, y0, args) -> (slots, code, value, stats)``: re-``init`` the ``fresh`` slots
    (``live``: holding a problem), then up to ``segment`` steps. ``arrays`` is the
    array part of the solver, ``static_solver`` the rest (the cache key);
    ``compiler_options``: XLA's, as ``(name, value)`` pairs."""
    # frictionfit's parameters are logistic coordinates: a vanished column is one on its bound
    options, tags = {"jac": jac, "bounded": True}, frozenset()

    def fn_aux(y, args):
        return fn(y, args), None

    def init(solver, y0, args):
        f_struct, aux_struct = jax.eval_shape(fn_aux, y0, args)
        state = solver.init(fn_aux, y0, args, options, f_struct, aux_struct, tags)
        stop, result = solver.terminate(fn_aux, y0, args, options, state, tags)
        return state, stop | (result != optx.RESULTS.successful), result

    def step(solver, y, state, args):
        y, state, _ = solver.step(fn_aux, y, args, options, state, tags)
        stop, result = solver.terminate(fn_aux, y, args, options, state, tags)
        finite = jnp.all(jnp.isfinite(y))
        result = optx.RESULTS.where(finite, result, optx.RESULTS.nonfinite)
        return y, state, stop | (result != optx.RESULTS.successful), result

    def finish(solver, slot: _Slots, state, args):
        result = optx.RESULTS.where(slot.stop, slot.result,
                                    optx.RESULTS.nonlinear_max_steps_reached)
        code = jnp.where(slot.stop | (slot.steps >= max_steps), _status(result), RUNNING)
        value, _, stats = solver.postprocess(fn_aux, slot.y, None, args, options, state, tags,
                                             result)
        return code, value, eqx.filter(stats, eqx.is_array)

    def start(solver, live, y0, args):
        state, stop, result = eqx.filter_vmap(lambda y, a: init(solver, y, a))(y0, args)
        dynamic, static = eqx.partition(state, eqx.is_array)
        return _Slots(y0, dynamic, jnp.zeros(y0.shape[0], int), stop | ~live, result), static

    def run(arrays, slots: _Slots, fresh, live, y0, args):
        solver = eqx.combine(arrays, static_solver)
        static = start(solver, live, y0, args)[1]  # traced only: the array part is unused
        slots = jax.lax.cond(jnp.any(fresh), lambda s: _where_slots(
            fresh, start(solver, live, y0, args)[0], s), lambda s: s, slots)

        def running(s):
            return ~s.stop & (s.steps < max_steps)

        def body(carry):
            i, s = carry
            state = eqx.combine(s.state, static)
            y, state, stop, result = eqx.filter_vmap(
                lambda *a: step(solver, *a))(s.y, state, args)
            new = _Slots(y, eqx.filter(state, eqx.is_array), s.steps + 1, stop, result)
            return i + 1, _where_slots(running(s), new, s)

        _, slots = jax.lax.while_loop(lambda c: (c[0] < segment) & jnp.any(running(c[1])),
                                      body, (0, slots))
        code, value, stats = eqx.filter_vmap(lambda *a: finish(solver, *a))(
            slots, eqx.combine(slots.state, static), args)
        return slots, code, value, stats

    xla = dict(compiler_options) or None
    return (jax.jit(lambda arrays, *a: start(eqx.combine(arrays, static_solver), *a)[0],
                    compiler_options=xla),
            jax.jit(run, compiler_options=xla))


def solve_pooled(solver: optx.AbstractLeastSquaresSolver, fn: Callable, y0: np.ndarray, args,
                 *, pool_size: int, max_steps: int, segment: int = 4, threads: int = 1,
                 jac: str = "fwd", progress: Callable[[int], object] | None = None,
                 solver_stats: bool = False, compiler_options: Mapping[str, object] | None = None):
    """Solve every problem (rows of ``y0`` and of each ``args`` leaf) with ``solver``.

    ``fn(y, args) -> residuals`` for one problem. Returns ``(y, status, steps)`` as
    NumPy arrays: the solution (the start where it is not finite), a
    :class:`~frictionfit.errors.Status` code and the steps taken, per problem; with
    ``solver_stats``, also the array statistics of the solver's ``postprocess`` at the
    solution, name -> one row per problem (e.g. ``J^T J`` of
    :class:`~frictionfit.fit.solver.BatchedLevenbergMarquardt`: no second Jacobian).
    ``pool_size`` slots; ``segment`` steps per compiled call; ``threads`` host
    threads, a pool each (:func:`in_threads`; the split does not change results);
    ``progress(k)`` is called as ``k`` more problems finish. ``compiler_options``: XLA's
    for the compiled calls (e.g. :data:`~frictionfit.models.measurement.HOST_LOOP_COMPILER_OPTIONS`
    where ``fn``'s work is the compiled contact loop).
    """
    if not isinstance(solver, optx.AbstractLeastSquaresSolver):
        raise FitError(f"{type(solver).__name__} is not an optimistix least-squares solver")
    arrays, static = eqx.partition(solver, eqx.is_array)
    fns = _segment_fn(static, fn, segment, max_steps, jac,
                      tuple(sorted((compiler_options or {}).items())))
    out = in_threads(lambda share, device: _solve_serial(
        fns, arrays, y0[share], jax.tree_util.tree_map(lambda a: a[share], args), pool_size, device,
        progress), y0.shape[0], pool_size, threads)
    return out if solver_stats else out[:3]


def pool_sizes(pool_size: int) -> list[int]:
    """The pool's sizes, largest first: ``pool_size``, then ``/4`` and ``/16`` (at least 4
    slots) for the tail of slow problems once no problem waits."""
    return sorted({pool_size} | {pool_size // d for d in (4, 16) if pool_size // d >= 4},
                  reverse=True)


def in_threads(solve_share: Callable, n: int, pool_size: int, threads: int):
    """``solve_share(rows, device)`` over contiguous shares of ``n`` problems, one host
    thread each (at most one per full pool: ``n // pool_size``), thread ``i`` on JAX
    device ``i`` (mod the device count; several CPU devices need
    ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` before JAX starts); the tuple
    of per-problem arrays of the shares, concatenated. Each problem's result does not
    depend on its pool's other problems, so the split does not change results."""
    threads = max(1, min(int(threads), n // max(pool_size, 1)))
    if threads == 1:
        return solve_share(slice(0, n), None)
    bounds = np.linspace(0, n, threads + 1).astype(int)
    shares = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    devices = jax.local_devices()
    with ThreadPoolExecutor(max_workers=threads) as ex:
        parts = list(ex.map(lambda i: solve_share(shares[i], devices[i % len(devices)]),
                            range(threads)))
    return jax.tree_util.tree_map(lambda *leaves: np.concatenate(leaves), *parts)


def _solve_serial(fns, arrays, y0: np.ndarray, args, pool_size: int, device, progress):
    """:func:`solve_pooled` in the calling thread: one pool on ``device`` (or the default)."""
    start, run = fns
    n = y0.shape[0]
    y_out, code_out, steps_out = y0.copy(), np.full(n, int(Status.MAX_STEPS)), np.zeros(n, int)
    stats_out = None  # name -> (n, ...) once the first call shows the shapes
    sizes = pool_sizes(pool_size)
    b = sizes[0]
    slot_y0 = np.repeat(y0[:1], b, axis=0)
    slot_args = jax.tree_util.tree_map(lambda a: np.repeat(a[:1], b, axis=0), args)
    owner, fresh, queue, slots = np.full(b, -1), np.zeros(b, bool), 0, None
    while True:
        rows = np.flatnonzero(owner < 0)[: n - queue]
        trials = np.arange(queue, queue + rows.size)
        queue += rows.size
        owner[rows], fresh[rows], slot_y0[rows] = trials, True, y0[trials]
        for leaf, whole in zip(jax.tree_util.tree_leaves(slot_args),
                               jax.tree_util.tree_leaves(args), strict=True):
            leaf[rows] = whole[trials]
        busy = np.flatnonzero(owner >= 0)
        if busy.size == 0:
            return y_out, code_out, steps_out, stats_out or {}
        smaller = [s for s in sizes if s >= busy.size]
        if queue == n and smaller[-1] < b:  # only a tail is left: shrink the pool
            b = smaller[-1]
            keep = np.concatenate([busy, np.flatnonzero(owner < 0)])[:b]
            slots, slot_y0, slot_args, owner, fresh = jax.tree_util.tree_map(
                lambda a, k=keep: a[k], (slots, slot_y0, slot_args, owner, fresh))
        # copies: on the CPU a device array may share the host buffer, refilled in place
        inputs = jax.device_put(jax.tree_util.tree_map(np.array, (owner >= 0, slot_y0,
                                                                  slot_args)), device)
        if slots is None:  # the first call: every slot starts here
            slots, fresh[:] = start(arrays, *inputs), False
        slots, code, value, stats = run(arrays, slots, fresh, *inputs)
        code = np.asarray(code)  # waits for the call: only now may its inputs change
        fresh[:] = False
        done = np.flatnonzero((owner >= 0) & (code != RUNNING))
        trials = owner[done]
        value = np.asarray(value)[done]
        y_out[trials] = np.where(np.all(np.isfinite(value), axis=1, keepdims=True),
                                 value, y0[trials])
        code_out[trials], steps_out[trials] = code[done], np.asarray(slots.steps)[done]
        if stats_out is None:
            stats_out = {k: np.full((n, *np.shape(v)[1:]), np.nan) for k, v in stats.items()}
        for k, v in stats.items():
            stats_out[k][trials] = np.asarray(v)[done]
        owner[done] = -1
        if progress is not None and done.size:
            progress(int(done.size))
