"""The compiled loop of :mod:`frictionfit.models._forward` as XLA's own operations.

The batch loops (the channel; the channel and its Jacobian; the weighted normal equations)
are one C function (numba's ``cfunc``) registered with XLA as a foreign-function target
(:data:`TARGET`) and called from JAX with :func:`jax.ffi.ffi_call`. A program that calls it
names the target, where a host callback would hold a Python object, so JAX keeps it in its
persistent compilation cache and a new process loads it instead of compiling it again.

The target reads XLA's call frame (``xla/ffi/api/c_api.h``, which jaxlib ships) itself: the
frame's arguments and results are buffers (a data pointer and dimensions) in the order
:func:`values`, :func:`jacobian` and :func:`normal_equations` pass them, the last two
arguments its settings (which loop, the stroke, ...) and the law's lanes. The arguments of
each call are broadcast to the same leading (batch) axes, as ``vmap`` leaves them; the loop
takes those axes as its rows. When XLA asks the target for its metadata (the FFI version
it was built for), it answers and returns.
"""

from __future__ import annotations

import ctypes
from functools import cache

import jax
import jax.numpy as jnp
import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from frictionfit.models._forward import (
    _batch,
    _batch_normal,
    _batch_value,
    _lanes,
    threaded,
    threads,
)

__all__ = ["jacobian", "normal_equations", "values"]

#: The XLA FFI version the target is written for (``XLA_FFI_API_MAJOR``, ``_MINOR``): the
#: call frame, buffers and metadata of 0.1 (jaxlib 0.5-0.7), which later versions extend at
#: their ends and accept from a handler.
_API_VERSION = (0, 1)
_METADATA_EXTENSION = 1  # XLA_FFI_Extension_Metadata
_API_VERSION_SIZE = 28  # sizeof(XLA_FFI_Api_Version) up to its last field
# 64-bit words of XLA_FFI_CallFrame: extension_start; args.size, args.args;
# rets.size, rets.rets
_EXTENSION, _N_ARGS, _ARGS, _N_RETS, _RETS = 1, 7, 9, 12, 14


@intrinsic
def _address(typingctx, word):
    """A 64-bit integer read from memory as the pointer it holds."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)
    return types.voidptr(types.int64), codegen


@numba.njit(inline="always")
def _words(word, n):
    """``n`` 64-bit words at the address ``word``."""
    return numba.carray(_address(word), n, np.int64)


@numba.njit(inline="always")
def _answered_metadata(frame):
    """If XLA's call asks for the target's metadata, write it and return True (the frame
    then holds nothing else)."""
    head = numba.carray(frame, _EXTENSION + 1, np.int64)
    if head[_EXTENSION] == 0:
        return False
    base = _words(head[_EXTENSION], 4)  # struct_size, type, next, metadata
    if base[1] & 0xFFFFFFFF != _METADATA_EXTENSION:
        return False
    meta = _words(base[3], 5)  # struct_size, api_version (4 words), traits
    meta[1] = _API_VERSION_SIZE
    meta[2] = 0  # api_version.extension_start
    meta[3] = _API_VERSION[0] | (_API_VERSION[1] << 32)
    meta[4] = 0  # no traits
    return True


@numba.njit(inline="always")
def _flat(word, dtype):
    """A buffer (XLA_FFI_Buffer: struct_size, extension_start, dtype, data, rank, dims) as a
    flat array, and its last dimension (1 for a scalar)."""
    fields = _words(word, 6)
    dims = _words(fields[5], fields[4])
    size, last = 1, 1
    for d in dims:
        size *= d
        last = d
    return numba.carray(_address(fields[3]), size, dtype), last


@numba.njit(inline="always")
def _rows(word, shape):
    """A float64 buffer as ``shape`` (its leading axes flattened into the first)."""
    return _flat(word, np.float64)[0].reshape(shape)


@numba.njit(inline="always")
def _call_frame(frame):
    """The frame's argument and result words, the rows (the leading axes' size), and the
    settings (stroke, rig columns, threads, kind) and lanes of the last two arguments (a
    call to execute: not a metadata query)."""
    head = numba.carray(frame, _RETS + 1, np.int64)
    args, rets = _words(head[_ARGS], head[_N_ARGS]), _words(head[_RETS], head[_N_RETS])
    direction, _ = _flat(args[5], np.float64)
    rows = direction.size
    settings, _ = _flat(args[args.size - 2], np.float64)
    lanes, _ = _flat(args[args.size - 1], np.int64)
    return args, rets, rows, settings[:4], lanes[:10]


@numba.njit(inline="always")
def _inputs(args, rows):
    """The common inputs: ``theta`` (rows, p), ``t`` (rows, n), ``commands``, ``signs``,
    ``stretch`` (rows, c), ``direction`` (rows,)."""
    theta, p = _flat(args[0], np.float64)
    t, n = _flat(args[1], np.float64)
    commands, c = _flat(args[2], np.float64)
    signs, _ = _flat(args[3], np.float64)
    stretch, _ = _flat(args[4], np.float64)
    direction, _ = _flat(args[5], np.float64)
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
    """The XLA target: the batch loop the settings name, on the frame's buffers (its
    threaded twin where the settings allow more than one thread)."""
    if _answered_metadata(frame):
        return _address(0)
    args, rets, rows, settings, lanes = _call_frame(frame)
    if rows == 0:
        return _address(0)
    inputs = _inputs(args, rows)
    theta, t = inputs[0], inputs[1]
    n, p, stroke, rig = t.shape[1], theta.shape[1], settings[0], np.int64(settings[1])
    n_threads, kind = np.int64(settings[2]), np.int64(settings[3])
    if kind == _VALUES:
        value = _rows(rets[0], (rows, n))
        if n_threads > 1:
            _batch_value_threaded(*inputs, stroke, lanes, n_threads, value)
        else:
            _batch_value(*inputs, stroke, lanes, 1, value)
    elif kind == _JACOBIAN:
        value, columns = _rows(rets[0], (rows, n)), _rows(rets[1], (rows, n, p))
        if n_threads > 1:
            _batch_threaded(*inputs, stroke, lanes, rig, n_threads, value, columns)
        else:
            _batch(*inputs, stroke, lanes, rig, 1, value, columns)
    else:
        y, weight = _rows(args[6], (rows, n)), _rows(args[7], (rows, n))
        cost, ctc, ctr = (_rows(rets[0], (rows,)), _rows(rets[1], (rows, p, p)),
                          _rows(rets[2], (rows, p)))
        if n_threads > 1:
            _batch_normal_threaded(*inputs, y, weight, stroke, lanes, rig, n_threads, cost,
                                   ctc, ctr)
        else:
            _batch_normal(*inputs, y, weight, stroke, lanes, rig, 1, cost, ctc, ctr)
    return _address(0)


#: The target's name. JAX's persistent cache keeps programs that name it from one version
#: of frictionfit to the next: a change of its arguments' layout needs a new name.
TARGET = "frictionfit_contact_loop_v1"


@cache
def _registered():
    """Compile (or load) the target and register it with XLA, once per process; the
    compiled target is kept (its code lives as long as it does). numba's threads are
    started first: a target loaded from numba's cache links to their runtime."""
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
