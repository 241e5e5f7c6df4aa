"""The contact loop's XLA target checks XLA's call frame before it reads a buffer: called
here directly with call frames built by hand (``ctypes``, the layout of ``c_api.h``) and a
fake API whose ``XLA_FFI_Error_Create`` records the message."""

import ctypes

import numpy as np
import pytest

from frictionfit.models import _ffi, _xla
from frictionfit.models._forward import channel_values
from frictionfit.models.measurement import LAWS

if not _xla.usable():
    pytest.skip("the contact loop's XLA target is off here", allow_module_level=True)

c_int64_p = ctypes.POINTER(ctypes.c_int64)


class Buffer(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("dtype", ctypes.c_int), ("data", ctypes.c_void_p), ("rank", ctypes.c_int64),
                ("dims", c_int64_p)]


class Args(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("size", ctypes.c_int64), ("types", ctypes.POINTER(ctypes.c_int)),
                ("args", ctypes.POINTER(ctypes.c_void_p))]


class Frame(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("api", ctypes.c_void_p), ("ctx", ctypes.c_void_p), ("stage", ctypes.c_int),
                ("args", Args), ("rets", Args), ("attrs", ctypes.c_int64 * 6),
                ("future", ctypes.c_void_p)]


class ErrorArgs(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("message", ctypes.c_char_p), ("errc", ctypes.c_int)]


CREATE = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(ErrorArgs))


class Api(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("version_size", ctypes.c_size_t), ("version_extension", ctypes.c_void_p),
                ("major", ctypes.c_int), ("minor", ctypes.c_int),
                ("internal_api", ctypes.c_void_p), ("error_create", CREATE)]


def test_the_hand_built_structs_have_the_offsets_the_target_reads():
    for (struct, field), offset in _ffi.OFFSETS.items():
        cls = {"XLA_FFI_CallFrame": Frame, "XLA_FFI_Args": Args, "XLA_FFI_Rets": Args,
               "XLA_FFI_Buffer": Buffer, "XLA_FFI_Error_Create_Args": ErrorArgs}.get(struct)
        if cls is not None and field in dict(cls._fields_):
            assert getattr(cls, field).offset == offset, (struct, field)


class Call:
    """A call frame of the target's values loop (kind 0) on one row of ``no_peak2``, and a
    fake API that records the errors the target makes."""

    def __init__(self):
        rng = np.random.default_rng(3)
        n, names = 200, LAWS["no_peak2"]
        self.t = np.linspace(0.0, 2.0, n)[None]
        self.theta = np.array([[0.1, 0.01, 0.05, 8.0, 0.6, 0.3, 0.15, 0.4, 1.2, 0.05, 0.02,
                                0.01, 0.12, 0.1]])
        self.inputs = [self.theta, self.t, np.array([[0.05, 1.05]]), np.array([[1.0, -1.0]]),
                       1 + 0.1 * rng.standard_normal((1, 2)), np.array([1.0])]
        self.settings = np.array([[1.3, 0.0, 1.0, 0.0]])
        self.lanes = _xla._lanes(names)[None].copy()
        self.value = np.full((1, n), np.nan)
        self.want = channel_values(*self.inputs, names=names, stroke_mm=1.3)
        self.messages = []
        self._create = CREATE(self._record)
        self.api = Api(200, None, 24, None, 0, 3, None, self._create)
        self.keep = []
        self.frame = Frame(168, None, ctypes.addressof(self.api), None, 3,
                           self._list([*self.inputs, self.settings, self.lanes]),
                           self._list([self.value]))

    def _record(self, args):
        self.messages.append(args.contents.message.decode())
        return 12345  # an error's address, as XLA would return

    def buffer(self, array):
        dims = (ctypes.c_int64 * array.ndim)(*array.shape)
        dtype = 12 if array.dtype == np.float64 else 5 if array.dtype == np.int64 else 11
        buf = Buffer(48, None, dtype, array.ctypes.data, array.ndim, dims)
        self.keep += [array, dims, buf]
        return buf

    def _list(self, arrays):
        bufs = [self.buffer(a) for a in arrays]
        types = (ctypes.c_int * len(bufs))(*[1] * len(bufs))
        ptrs = (ctypes.c_void_p * len(bufs))(*[ctypes.addressof(b) for b in bufs])
        self.keep += [types, ptrs]
        return Args(40, None, len(bufs), types, ptrs)

    def arg(self, i) -> Buffer:
        return Buffer.from_address(self.frame.args.args[i])

    def __call__(self):
        return _xla._registered().ctypes(ctypes.addressof(self.frame))


def test_a_valid_frame_runs_the_loop():
    call = Call()
    assert call() is None and call.messages == []
    np.testing.assert_array_equal(call.value, call.want)


@pytest.mark.parametrize(("spoil", "message"), [
    (lambda c: setattr(c.frame, "struct_size", 176), "call frame is not of the size"),
    (lambda c: setattr(c.frame, "stage", 0), "another stage than execute"),
    (lambda c: setattr(c.arg(1), "dtype", 11), "float64 buffers then an int64"),
    (lambda c: setattr(c.arg(7), "dtype", 4), "float64 buffers then an int64"),
    (lambda c: setattr(c.arg(2), "struct_size", 40), "float64 buffers then an int64"),
    (lambda c: setattr(c.arg(0), "rank", 99), "float64 buffers then an int64"),
    (lambda c: setattr(c.frame.args, "size", 7), "float64 buffers then an int64"),
    (lambda c: setattr(c.frame.rets, "size", 0), "float64 buffers then an int64"),
    (lambda c: c.arg(1).dims.__setitem__(1, 400), "shapes disagree"),
    (lambda c: c.arg(3).dims.__setitem__(1, 1), "shapes disagree"),
    (lambda c: c.settings.__setitem__((0, 3), 1.0), "shapes disagree"),  # 2 results needed
    (lambda c: c.lanes.__setitem__((0, 0), 7), "lanes out of range"),
    (lambda c: c.lanes.__setitem__((0, 4), -1), "lanes out of range"),  # a 2nd branch alone
    (lambda c: c.settings.__setitem__((0, 1), 2.0), "lanes out of range"),
])
def test_a_frame_the_target_does_not_read_is_refused_with_xlas_error(spoil, message):
    call = Call()
    spoil(call)
    assert call() == 12345
    assert len(call.messages) == 1 and message in call.messages[0]
    assert np.isnan(call.value).all()  # nothing written


def test_an_api_of_an_unknown_version_is_left_untouched():
    """No error can be made through an API whose layout is unknown: nothing read, nothing
    written (the import-time check keeps the target from being registered there)."""
    call = Call()
    call.api.minor = 9
    assert call() is None and call.messages == []
    assert np.isnan(call.value).all()


@pytest.mark.parametrize("size", [36, 48])
def test_the_metadata_query_is_answered_within_the_struct_xla_passes(size):
    """``struct_size`` of the version written; ``state_type_id`` (FFI 0.3) only where XLA's
    struct is long enough to have it."""
    call = Call()
    metadata = (ctypes.c_int64 * 6)(size, -1, -1, -1, -1, -1)
    extension = (ctypes.c_int64 * 4)(32, 1, 0, ctypes.addressof(metadata))
    call.frame.extension_start = ctypes.addressof(extension)
    assert call() is None and call.messages == []
    words = list(metadata)
    assert words[:3] == [size, 24, 0]
    assert (words[3] & 0xFFFFFFFF, words[3] >> 32) == _ffi.KNOWN_VERSIONS[0]
    assert words[4] & 0xFFFFFFFF == 0  # no traits
    assert words[5] == (0 if size == 48 else -1)
    assert np.isnan(call.value).all()


def test_a_metadata_struct_too_short_is_refused():
    call = Call()
    metadata = (ctypes.c_int64 * 6)(24, -1, -1, -1, -1, -1)
    extension = (ctypes.c_int64 * 4)(32, 1, 0, ctypes.addressof(metadata))
    call.frame.extension_start = ctypes.addressof(extension)
    assert call() == 12345 and "metadata structs are shorter" in call.messages[0]
    assert list(metadata)[1:] == [-1] * 5
