"""XLA's call frame read by the contact loop's target (numba), every struct checked first.

The target (:mod:`frictionfit.models._xla`) is a C function XLA calls with a pointer to its
``XLA_FFI_CallFrame``. These functions read that frame at the offsets
:mod:`frictionfit.models._ffi` holds; :func:`frame_problem` checks, before any buffer is
read, the frame's size, execution stage, argument and result counts, that each is a buffer
of the dtype and struct size expected, and that their shapes agree, so that no loop reads or
writes past a buffer. A problem is answered with XLA's own error (:func:`invalid`), which
JAX raises.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from frictionfit.models import _ffi

__all__ = ["error_maker", "flat", "frame_problem", "invalid", "metadata", "rows_of"]

#: The XLA FFI version the target answers XLA's metadata query with: the first of the
#: versions whose layout it reads (:data:`~frictionfit.models._ffi.KNOWN_VERSIONS`), which
#: later versions accept from a handler.
_API_VERSION = _ffi.KNOWN_VERSIONS[0]
_LAST_MINOR = _ffi.KNOWN_VERSIONS[1][1]
_O, _S, _V = _ffi.OFFSETS, _ffi.SIZES, _ffi.VALUES
_FRAME_SIZE = _S["XLA_FFI_CallFrame"]
# 64-bit words (and 32-bit halves: _I_) of the structs read (layouts in _ffi)
_EXTENSION = _O["XLA_FFI_CallFrame", "extension_start"] // 8
_API = _O["XLA_FFI_CallFrame", "api"] // 8
_I_STAGE = _O["XLA_FFI_CallFrame", "stage"] // 4
_ARGS = _O["XLA_FFI_CallFrame", "args"] // 8  # XLA_FFI_Args: struct_size, _, size, types, args
_RETS = _O["XLA_FFI_CallFrame", "rets"] // 8
_N, _TYPES, _PTRS = (_O["XLA_FFI_Args", f] // 8 for f in ("size", "types", "args"))
_I_API_MAJOR = (_O["XLA_FFI_Api", "api_version"] + _O["XLA_FFI_Api_Version", "major_version"]) // 4
_API_CREATE = _O["XLA_FFI_Api", "XLA_FFI_Error_Create"] // 8
_B_DTYPE = _O["XLA_FFI_Buffer", "dtype"] // 4
_B_DATA, _B_RANK, _B_DIMS = (_O["XLA_FFI_Buffer", f] // 8 for f in ("data", "rank", "dims"))
_META = _O["XLA_FFI_Metadata_Extension", "metadata"] // 8
_M_VERSION = _O["XLA_FFI_Metadata", "api_version"] // 8
_I_TRAITS = _O["XLA_FFI_Metadata", "traits"] // 4
_M_STATE = _ffi.OPTIONAL_OFFSETS["XLA_FFI_Metadata", "state_type_id"] // 8
_F64, _S64 = _V["XLA_FFI_DataType_F64"], _V["XLA_FFI_DataType_S64"]
_BUFFER, _EXECUTE = _V["XLA_FFI_ArgType_BUFFER"], _V["XLA_FFI_ExecutionStage_EXECUTE"]
_ARGS_SIZE, _BUFFER_SIZE = _S["XLA_FFI_Args"], _S["XLA_FFI_Buffer"]
_META_EXTENSION_SIZE, _META_SIZE = _S["XLA_FFI_Metadata_Extension"], _S["XLA_FFI_Metadata"]
_VERSION_SIZE = _S["XLA_FFI_Api_Version"]
_METADATA_TYPE = _V["XLA_FFI_Extension_Metadata"]
_I_EXTENSION_TYPE = _O["XLA_FFI_Extension_Base", "type"] // 4
_MAX_RANK = 8  # more leading axes than any call of the target has


@intrinsic
def _address(typingctx, word):
    """A 64-bit integer read from memory as the pointer it holds."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)
    return types.voidptr(types.int64), codegen


@intrinsic
def invalid(typingctx, create, text):
    """XLA's error (``XLA_FFI_Error*``, code INVALID_ARGUMENT) with the literal ``text``,
    made by the API's ``XLA_FFI_Error_Create`` at address ``create``."""
    if not isinstance(text, types.StringLiteral):
        return None
    message = text.literal_value

    def codegen(context, builder, signature, args):
        i64, i8p = ir.IntType(64), ir.IntType(8).as_pointer()
        block = builder.bitcast(cgutils.alloca_once(builder, ir.ArrayType(i64, 4)),
                                i64.as_pointer())
        text_ptr = builder.ptrtoint(context.insert_const_string(builder.module, message), i64)
        fields = (ir.Constant(i64, _S["XLA_FFI_Error_Create_Args"]), ir.Constant(i64, 0),
                  text_ptr, ir.Constant(i64, _V["XLA_FFI_Error_Code_INVALID_ARGUMENT"]))
        for i, value in enumerate(fields):  # struct_size, extension_start, message, errc
            builder.store(value, builder.gep(block, [ir.Constant(ir.IntType(32), i)]))
        fn = builder.inttoptr(args[0], ir.FunctionType(i8p, [i8p]).as_pointer())
        return builder.call(fn, [builder.bitcast(block, i8p)])
    return types.voidptr(types.int64, text), codegen


@numba.njit(inline="always")
def _words(word, n):
    """``n`` 64-bit words at the address ``word``."""
    return numba.carray(_address(word), n, np.int64)


@numba.njit(inline="always")
def _halves(word, n):
    """``n`` 32-bit integers at the address ``word``."""
    return numba.carray(_address(word), n, np.int32)


@numba.njit(inline="always")
def error_maker(frame):
    """The address of the frame's API's ``XLA_FFI_Error_Create``; 0 where the frame or its
    API is not of a layout the target knows (no error can then be made)."""
    size = numba.carray(frame, 1, np.int64)[0]
    if size < (_API + 1) * 8:
        return 0
    api = numba.carray(frame, _API + 1, np.int64)[_API]
    if api == 0 or _words(api, 1)[0] < (_API_CREATE + 1) * 8:
        return 0
    version = _halves(api, _I_API_MAJOR + 2)
    if version[_I_API_MAJOR] != _API_VERSION[0] or not (
            _API_VERSION[1] <= version[_I_API_MAJOR + 1] <= _LAST_MINOR):
        return 0
    return _words(api, _API_CREATE + 1)[_API_CREATE]


@numba.njit(inline="always")
def metadata(extension):
    """Answer XLA's metadata query at ``extension`` (the frame's first extension, of the
    metadata type): 0, or 1 where XLA's structs are shorter than the fields written."""
    if _words(extension, 1)[0] < _META_EXTENSION_SIZE:
        return 1
    meta = _words(extension, _META + 1)[_META]
    size = _words(meta, 1)[0]
    if size < _META_SIZE:
        return 1
    words, halves = _words(meta, _M_VERSION + 3), _halves(meta, _I_TRAITS + 1)
    words[_M_VERSION] = _VERSION_SIZE  # api_version.struct_size
    words[_M_VERSION + 1] = 0  # api_version.extension_start
    halves[2 * _M_VERSION + 4] = _API_VERSION[0]
    halves[2 * _M_VERSION + 5] = _API_VERSION[1]
    halves[_I_TRAITS] = 0  # no traits
    if size >= (_M_STATE + 1) * 8:
        _words(meta, _M_STATE + 1)[_M_STATE] = 0  # XLA_FFI_UNKNOWN_TYPE_ID: stateless
    return 0


@numba.njit(inline="always")
def flat(word, dtype):
    """A buffer (XLA_FFI_Buffer: struct_size, extension_start, dtype, data, rank, dims) as a
    flat array, and its last dimension (1 for a scalar)."""
    fields = _words(word, _B_DIMS + 1)
    size, last, _ = _dims(word)
    return numba.carray(_address(fields[_B_DATA]), size, dtype), last


@numba.njit(inline="always")
def rows_of(word, shape):
    """A float64 buffer as ``shape`` (its leading axes flattened into the first)."""
    return flat(word, np.float64)[0].reshape(shape)




@numba.njit(inline="always")
def _dims(word):
    """A checked buffer's size, last and second-to-last dimensions (1 where it has none)."""
    fields = _words(word, _B_DIMS + 1)
    rank, size, last, before = fields[_B_RANK], 1, 1, 1
    if rank > 0:
        dims = _words(fields[_B_DIMS], rank)
        for d in dims:
            size *= d
        last = dims[rank - 1]
        if rank > 1:
            before = dims[rank - 2]
    return size, last, before


@numba.njit(inline="always")
def _is_buffer(kind, word, dtype):
    """Whether ``word`` is a buffer (type ``kind``) of ``dtype`` whose fields the target
    reads are there: a struct long enough, a rank 0-8 with its dimensions, none negative."""
    if kind != _BUFFER or word == 0 or _words(word, 1)[0] < _BUFFER_SIZE:
        return False
    fields = _words(word, _B_DIMS + 1)
    rank = fields[_B_RANK]
    if _halves(word, _B_DTYPE + 1)[_B_DTYPE] != dtype or not 0 <= rank <= _MAX_RANK:
        return False
    if rank > 0:
        if fields[_B_DIMS] == 0:
            return False
        for d in _words(fields[_B_DIMS], rank):
            if d < 0:
                return False
    return fields[_B_DATA] != 0 or _dims(word)[0] == 0


@numba.njit(inline="always")
def _buffers(frame, at, last_dtype):
    """The buffers' words of the frame's arguments (``at`` = its ``args`` word) or results,
    or an empty array where one is not a buffer the target reads (``last_dtype``: the
    last's dtype; the others' float64)."""
    head = numba.carray(frame, at + _PTRS + 1, np.int64)
    if head[at] < _ARGS_SIZE or not 0 < head[at + _N] <= 16:
        return np.empty(0, np.int64)
    n = head[at + _N]
    kinds, words = _halves(head[at + _TYPES], n), _words(head[at + _PTRS], n)
    for i in range(n):
        if not _is_buffer(kinds[i], words[i], last_dtype if i == n - 1 else _F64):
            return np.empty(0, np.int64)
    return words


#: :func:`frame_problem`'s answers: none; a metadata query; the frame's size; its stage;
#: arguments or results that are not the buffers expected; shapes that disagree; settings
#: or lanes the loops cannot take.
OK, QUERY, FRAME, STAGE, BUFFERS, SHAPES, SETTINGS = range(7)


@numba.njit(inline="always")
def _shapes_agree(args, rets):
    """Whether the arguments' and results' shapes agree: ``theta`` (rows, p), ``t`` (rows,
    n), the movements (rows, c), ``direction`` (rows,), then ``y``, ``weight`` (rows, n)
    where 10 arguments, settings (rows, 4), lanes (rows, 10); the results those the
    settings' kind names. Reads only the buffers' dimensions and the settings' first row."""
    rows = _dims(args[5])[0]
    size_p, p, _ = _dims(args[0])
    size_n, n, _ = _dims(args[1])
    size_c, c, _ = _dims(args[2])
    if size_p != rows * p or size_n != rows * n or size_c != rows * c or p < 8 or n < 2:
        return False
    for i in (3, 4):
        if _dims(args[i])[:2] != (rows * c, c):
            return False
    if args.size == 10:
        for i in (6, 7):
            if _dims(args[i])[:2] != (rows * n, n):
                return False
    if _dims(args[args.size - 2])[:2] != (rows * 4, 4):
        return False
    if _dims(args[args.size - 1])[:2] != (rows * 10, 10):
        return False
    if rows == 0:
        return True
    kind = flat(args[args.size - 2], np.float64)[0][3]
    if kind == 0.0:
        return args.size == 8 and rets.size == 1 and _dims(rets[0])[:2] == (rows * n, n)
    if kind == 1.0:
        return (args.size == 8 and rets.size == 2 and _dims(rets[0])[:2] == (rows * n, n)
                and _dims(rets[1]) == (rows * n * p, p, n))
    return (kind == 2.0 and args.size == 10 and rets.size == 3 and _dims(rets[0])[0] == rows
            and _dims(rets[1])[:2] == (rows * p * p, p) and _dims(rets[2])[:2] == (rows * p, p))


@numba.njit(inline="always")
def _settings_valid(args):
    """Whether the first row's settings (stroke, rig columns 0 or 3, threads >= 1) and lanes
    (each -1 or an index of the law's ``p - 7`` parameters; ``k`` and ``f_kin`` there, a
    static excess with its slip length, each branch with its time and the second only with
    the first) are ones the loops index safely."""
    settings = flat(args[args.size - 2], np.float64)[0]
    lanes = flat(args[args.size - 1], np.int64)[0]
    m = _dims(args[0])[1] - 7
    if (settings[1] != 0.0 and settings[1] != 3.0) or not settings[2] >= 1.0:
        return False
    for lane in lanes:
        if not -1 <= lane < m:
            return False
    k, f_kin, excess, length = lanes[0], lanes[1], lanes[2], lanes[3]
    rf, tau, rf2, tau2 = lanes[4], lanes[5], lanes[6], lanes[7]
    return (k >= 0 and f_kin >= 0 and (excess < 0 or length >= 0) and (rf < 0 or tau >= 0)
            and (rf2 < 0 or (tau2 >= 0 and rf >= 0)))


@numba.njit(inline="always")
def frame_problem(frame):
    """What is wrong with XLA's call frame for the target (:data:`OK` where nothing is; the
    frame's API already checked by :func:`error_maker`)."""
    if numba.carray(frame, 1, np.int64)[0] != _FRAME_SIZE:
        return FRAME
    head = numba.carray(frame, _FRAME_SIZE // 8, np.int64)
    if head[_EXTENSION] != 0:
        extension = head[_EXTENSION]
        if _words(extension, 1)[0] >= (_I_EXTENSION_TYPE // 2 + 1) * 8 and _halves(
                extension, _I_EXTENSION_TYPE + 1)[_I_EXTENSION_TYPE] == _METADATA_TYPE:
            return QUERY
    if numba.carray(frame, _I_STAGE + 1, np.int32)[_I_STAGE] != _EXECUTE:
        return STAGE
    args, rets = _buffers(frame, _ARGS, _S64), _buffers(frame, _RETS, _F64)
    if args.size not in (8, 10) or rets.size == 0:
        return BUFFERS
    if not _shapes_agree(args, rets):
        return SHAPES
    if _dims(args[5])[0] > 0 and not _settings_valid(args):
        return SETTINGS
    return OK

