"""The compiled loop of :mod:`frictionfit.models._forward` as XLA's own operations, on the
CPU where the installed jaxlib's FFI is one the target knows; JAX's own scan elsewhere.

The batch loops (the channel; the channel and its Jacobian; the weighted normal equations)
are one C function (numba's ``cfunc``) registered with XLA as a foreign-function target
(:data:`TARGET`) and called from JAX with :func:`jax.ffi.ffi_call`. A program that calls it
names the target, where a host callback would hold a Python object, so JAX keeps it in its
persistent compilation cache and a new process loads it instead of compiling it again.

The target reads XLA's call frame (``xla/ffi/api/c_api.h``, which jaxlib ships) itself
(:mod:`frictionfit.models._xla_frame`): the frame's arguments and results are buffers in
the order :func:`values`, :func:`jacobian` and :func:`normal_equations` pass them, the last
two arguments its settings (which loop, the stroke, ...) and the law's lanes. The arguments
of each call are broadcast to the same leading (batch) axes, as ``vmap`` leaves them; the
loop takes those axes as its rows. It answers XLA's metadata query, and checks every struct
and shape before it reads a buffer, answering a problem with XLA's error.

Whether the target is used (:func:`usable`): not where ``FRICTIONFIT_NATIVE=0``, nor where
the installed jaxlib's FFI header differs from the layout the target reads
(:func:`frictionfit.models._ffi.layout_problem`: checked at import, a ``RuntimeWarning``
naming both versions). :func:`on_cpu` then picks the target on the CPU and the pure-JAX
twin on any other platform.
"""

from __future__ import annotations

import ctypes
import os
import warnings
from collections.abc import Callable
from functools import cache

import jax
import jax.numpy as jnp
import numba
import numpy as np
from numba import types

from frictionfit.models import _ffi
from frictionfit.models import _xla_frame as fr
from frictionfit.models._forward import (
    _batch,
    _batch_normal,
    _batch_value,
    _lanes,
    threaded,
    threads,
)

__all__ = ["TARGET", "jacobian", "native_requested", "normal_equations", "on_cpu", "usable",
           "values"]


@numba.njit(inline="always")
def _call_frame(frame):
    """The frame's argument and result words, the rows (the leading axes' size), and the
    settings (stroke, rig columns, threads, kind) and lanes of the last two arguments (a
    checked call to execute: not a metadata query)."""
    head = numba.carray(frame, fr._RETS + fr._PTRS + 1, np.int64)
    args = fr._words(head[fr._ARGS + fr._PTRS], head[fr._ARGS + fr._N])
    rets = fr._words(head[fr._RETS + fr._PTRS], head[fr._RETS + fr._N])
    direction, _ = fr.flat(args[5], np.float64)
    rows = direction.size
    settings, _ = fr.flat(args[args.size - 2], np.float64)
    lanes, _ = fr.flat(args[args.size - 1], np.int64)
    return args, rets, rows, settings[:4], lanes[:10]


@numba.njit(inline="always")
def _inputs(args, rows):
    """The common inputs: ``theta`` (rows, p), ``t`` (rows, n), ``commands``, ``signs``,
    ``stretch`` (rows, c), ``direction`` (rows,)."""
    theta, p = fr.flat(args[0], np.float64)
    t, n = fr.flat(args[1], np.float64)
    commands, c = fr.flat(args[2], np.float64)
    signs, _ = fr.flat(args[3], np.float64)
    stretch, _ = fr.flat(args[4], np.float64)
    direction, _ = fr.flat(args[5], np.float64)
    return (theta.reshape((rows, p)), t.reshape((rows, n)), commands.reshape((rows, c)),
            signs.reshape((rows, c)), stretch.reshape((rows, c)), direction)


#: What the target computes, the 4th setting: the channel (rows, n); the channel and its
#: Jacobian (rows, n, p); the weighted cost (rows,), ``C^T C`` (rows, p, p) and ``C^T r``
#: (rows, p) with ``y`` and ``weight`` (rows, n) the 7th and 8th arguments.
_VALUES, _JACOBIAN, _NORMAL = 0, 1, 2


_batch_value_threaded = threaded(_batch_value)
_batch_threaded = threaded(_batch)
_batch_normal_threaded = threaded(_batch_normal)


def _target(frame):
    """The XLA target: the metadata query answered, or the frame checked, then the batch
    loop the settings name on its buffers (its threaded twin where the settings allow more
    than one thread); XLA's error where the frame is not one the target reads (nothing read
    or written where its API is not one the target knows: no error can be made)."""
    create = fr.error_maker(frame)
    if create == 0:
        return fr._address(0)
    problem = fr.frame_problem(frame)
    if problem == fr.QUERY:
        if fr.metadata(numba.carray(frame, fr._EXTENSION + 1, np.int64)[fr._EXTENSION]):
            return fr.invalid(create, "frictionfit_contact_loop: XLA's metadata structs are "
                              "shorter than the FFI version the target knows")
        return fr._address(0)
    if problem == fr.FRAME:
        return fr.invalid(create, "frictionfit_contact_loop: XLA's call frame is not of the "
                          "size the target reads (another XLA FFI version); set "
                          "FRICTIONFIT_NATIVE=0 to fit without it")
    if problem == fr.STAGE:
        return fr.invalid(create, "frictionfit_contact_loop: called at another stage than "
                          "execute")
    if problem == fr.BUFFERS:
        return fr.invalid(create, "frictionfit_contact_loop: expected 8 or 10 float64 buffers "
                          "then an int64 one, and 1-3 float64 results")
    if problem == fr.SHAPES:
        return fr.invalid(create, "frictionfit_contact_loop: the buffers' shapes disagree "
                          "(rows, samples, parameters, movements, results)")
    if problem == fr.SETTINGS:
        return fr.invalid(create, "frictionfit_contact_loop: settings or law lanes out of "
                          "range")
    args, rets, rows, settings, lanes = _call_frame(frame)
    if rows == 0:
        return fr._address(0)
    inputs = _inputs(args, rows)
    theta, t = inputs[0], inputs[1]
    n, p, stroke, rig = t.shape[1], theta.shape[1], settings[0], np.int64(settings[1])
    n_threads, kind = np.int64(settings[2]), np.int64(settings[3])
    if kind == _VALUES:
        value = fr.rows_of(rets[0], (rows, n))
        if n_threads > 1:
            _batch_value_threaded(*inputs, stroke, lanes, n_threads, value)
        else:
            _batch_value(*inputs, stroke, lanes, 1, value)
    elif kind == _JACOBIAN:
        value, columns = fr.rows_of(rets[0], (rows, n)), fr.rows_of(rets[1], (rows, n, p))
        if n_threads > 1:
            _batch_threaded(*inputs, stroke, lanes, rig, n_threads, value, columns)
        else:
            _batch(*inputs, stroke, lanes, rig, 1, value, columns)
    else:
        y, weight = fr.rows_of(args[6], (rows, n)), fr.rows_of(args[7], (rows, n))
        cost, ctc, ctr = (fr.rows_of(rets[0], (rows,)), fr.rows_of(rets[1], (rows, p, p)),
                          fr.rows_of(rets[2], (rows, p)))
        if n_threads > 1:
            _batch_normal_threaded(*inputs, y, weight, stroke, lanes, rig, n_threads, cost,
                                   ctc, ctr)
        else:
            _batch_normal(*inputs, y, weight, stroke, lanes, rig, 1, cost, ctc, ctr)
    return fr._address(0)


#: The target's name. JAX's persistent cache keeps programs that name it from one version
#: of frictionfit to the next: a change of its arguments' layout needs a new name.
TARGET = "frictionfit_contact_loop_v1"


def native_requested() -> bool:
    """Whether the compiled loops may be used: not where ``FRICTIONFIT_NATIVE`` is ``0``
    (or ``off``, ``false``, ``no``)."""
    return os.environ.get("FRICTIONFIT_NATIVE", "1").strip().lower() not in (
        "0", "off", "false", "no")


@cache
def usable() -> bool:
    """Whether the target may be used: requested (:func:`native_requested`) and the
    installed jaxlib's FFI header laid out as the target reads it (a ``RuntimeWarning``
    naming what differs, and both FFI versions, where it is not)."""
    if not native_requested():
        return False
    problem = _ffi.layout_problem()
    if problem is not None:
        warnings.warn(f"frictionfit's compiled contact loop is off: {problem}. Whole fits "
                      "run on the pure-JAX path (slower on the CPU, same results); set "
                      "FRICTIONFIT_NATIVE=0 to silence this.", RuntimeWarning, stacklevel=2)
    return problem is None


@cache
def _cpu_only() -> bool:
    """Whether JAX runs on the CPU alone in this process (no GPU or TPU backend)."""
    return jax.default_backend() == "cpu"


def on_cpu(native: Callable, pure: Callable) -> Callable:
    """``native`` where a program runs on the CPU and the target is :func:`usable`, else
    ``pure`` (same arguments and results). Where JAX has another backend than the CPU, the
    choice is :func:`jax.lax.platform_dependent`'s, made for each platform a program is
    lowered for (it traces both); where the CPU is JAX's only backend, ``native`` itself."""
    if not usable():
        return pure
    if _cpu_only():
        return native

    def either(*args):
        return jax.lax.platform_dependent(*args, cpu=native, default=pure)

    return either


@cache
def _registered():
    """Compile (or load) the target and register it with XLA, once per process; the
    compiled target is kept (its code lives as long as it does). numba's threads are
    started first: a target loaded from numba's cache links to their runtime."""
    if not usable():
        raise RuntimeError("the contact loop's XLA target is off (FRICTIONFIT_NATIVE=0, or "
                           "an XLA FFI layout it does not know): use the pure-JAX path")
    threads()
    compiled = numba.cfunc(types.voidptr(types.voidptr), cache=True)(_target)
    capsule = ctypes.pythonapi.PyCapsule_New
    capsule.restype = ctypes.py_object
    capsule.argtypes = (ctypes.c_void_p, ctypes.c_char_p, ctypes.c_void_p)
    jax.ffi.register_ffi_target(TARGET, capsule(compiled.address, None, None), platform="cpu")
    return compiled


def _call(kind: int, results: tuple, inputs: tuple, *, names: tuple[str, ...],
          stroke_mm: float, rig_columns: bool = False):
    """The target's loop ``kind`` on ``inputs`` (each with ``t``'s leading axes; float64)
    then the settings and lanes; ``results`` its result shapes."""
    _registered()
    theta, t = inputs[0], inputs[1]
    lead = t.shape[:-1]
    if theta.shape[:-1] != lead or any(np.shape(a)[:len(lead)] != lead for a in inputs[2:]):
        raise ValueError(f"the contact loop: every input needs t's leading axes {lead}; got shapes "
                         f"{[np.shape(a) for a in inputs]}")
    settings = jnp.broadcast_to(jnp.array([stroke_mm, 3.0 if rig_columns else 0.0,
                                           float(threads()), float(kind)]), (*lead, 4))
    lanes = jnp.broadcast_to(jnp.asarray(_lanes(tuple(names))), (*lead, 10))
    return jax.ffi.ffi_call(TARGET, results, vmap_method="broadcast_all")(
        *(jnp.asarray(a, dtype=jnp.float64) for a in inputs), settings, lanes)


def values(theta, t, commands, signs, stretch, direction, *, names: tuple[str, ...],
           stroke_mm: float):
    """:func:`~frictionfit.models._forward.channel_values` as a JAX operation (N,
    ``(..., n)``)."""
    return _call(_VALUES, jax.ShapeDtypeStruct(t.shape, jnp.float64),
                 (theta, t, commands, signs, stretch, direction), names=names,
                 stroke_mm=stroke_mm)


def jacobian(theta, t, commands, signs, stretch, direction, *, names: tuple[str, ...],
             stroke_mm: float, rig_columns: bool):
    """:func:`~frictionfit.models._forward.channel_jacobian` as a JAX operation."""
    shapes = (jax.ShapeDtypeStruct(t.shape, jnp.float64),
              jax.ShapeDtypeStruct((*t.shape, theta.shape[-1]), jnp.float64))
    return _call(_JACOBIAN, shapes,
                 (theta, t, commands, signs, stretch, direction), names=names,
                 stroke_mm=stroke_mm, rig_columns=rig_columns)


def normal_equations(theta, t, commands, signs, stretch, direction, y, weight, *,
                     names: tuple[str, ...], stroke_mm: float, rig_columns: bool):
    """:func:`~frictionfit.models._forward.weighted_normal_equations` as a JAX operation."""
    lead, p = t.shape[:-1], theta.shape[-1]
    shapes = (jax.ShapeDtypeStruct(lead, jnp.float64),
              jax.ShapeDtypeStruct((*lead, p, p), jnp.float64),
              jax.ShapeDtypeStruct((*lead, p), jnp.float64))
    return _call(_NORMAL, shapes,
                 (theta, t, commands, signs, stretch, direction, y, weight), names=names,
                 stroke_mm=stroke_mm, rig_columns=rig_columns)


usable()  # the installed jaxlib's FFI layout checked at import (a warning where unknown)
