"""A Python function that compiled programs call by name: :func:`register` and :func:`call`.

``jax.pure_callback`` puts a reference to this process's Python function into the program it lowers, so
neither JAX's persistent compilation cache nor swat_jax's program cache can give that program to another
process: every process traces, lowers and compiles it again. A function registered here is instead an
XLA FFI target (``jax.ffi.register_ffi_target``), which a program names by a string: the program carries
the target's name and string or integer attributes (which object of the process computes, with which
settings), and is the same program in every process that registers the same name. The caches keep it, and
a later process loads it and calls its own function of that name.

The target is a ctypes function pointer into Python, which reads XLA's FFI call frame (XLA's stable C API
for custom calls, major version 0): it answers XLA's metadata query with the API version it was written
against, and on the execute stage passes the buffers as NumPy arrays (views of XLA's memory, valid during
the call) to the Python function, which writes its results into the result arrays. An exception in the
function becomes an XLA error with its message, which JAX raises where the program runs. ctypes takes the
GIL for the call (JAX releases it while a program runs), as ``pure_callback`` does.

Unlike a ``pure_callback`` program, which JAX runs to its end before the call returns, such a program is
dispatched asynchronously on a CPU, as any other. A program still running when the interpreter exits
would call into Python after Python has stopped its threads (and can hang the exit): once a target is
registered, the interpreter's exit first waits for every computation whose results are alive
(:func:`_finish_running_programs`, run with the threading module's exit hooks, before thread pools stop).
"""

from __future__ import annotations

import ctypes
import threading
import traceback
from collections.abc import Callable, Mapping, Sequence

import jax
import numpy as np

HostFunction = Callable[[Sequence[np.ndarray], Sequence[np.ndarray], Mapping[str, str | int]], None]
"""What a registered function does: (arguments, results to fill, attributes by name)."""

API_VERSION = (0, 1)
"""The FFI C API version (major, minor) these structures follow (the call frame up to ``attrs``, the
buffer, the metadata extension); XLA accepts a handler of its major version and an older minor one."""
EXECUTE = 3
"""``XLA_FFI_ExecutionStage_EXECUTE``: the stage at which a handler computes."""
METADATA_EXTENSION = 1
"""``XLA_FFI_Extension_Metadata``: the extension with which XLA asks a handler for its API version."""
STRING_ATTRIBUTE, SCALAR_ATTRIBUTE = 4, 3
"""``XLA_FFI_AttrType_STRING`` and ``XLA_FFI_AttrType_SCALAR``."""
INTERNAL_ERROR = 13
"""``XLA_FFI_Error_Code_INTERNAL``."""
DTYPES = {
    1: np.bool_,
    2: np.int8,
    3: np.int16,
    4: np.int32,
    5: np.int64,
    6: np.uint8,
    7: np.uint16,
    8: np.uint32,
    9: np.uint64,
    10: np.float16,
    11: np.float32,
    12: np.float64,
}
"""``XLA_FFI_DataType`` to NumPy: the types a registered function can receive."""


_HEAD = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p)]
"""The first two fields of every structure of the C API: its size and its extensions."""


class _Extension(ctypes.Structure):
    pass


_Extension._fields_ = [
    ("struct_size", ctypes.c_size_t),
    ("type", ctypes.c_int),
    ("next", ctypes.POINTER(_Extension)),
]


class _Version(ctypes.Structure):
    _fields_ = [
        *_HEAD,
        ("major", ctypes.c_int),
        ("minor", ctypes.c_int),
    ]


class _Metadata(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("api_version", _Version), ("traits", ctypes.c_uint32)]


class _MetadataExtension(ctypes.Structure):
    _fields_ = [("base", _Extension), ("metadata", ctypes.POINTER(_Metadata))]


class _Values(ctypes.Structure):
    """``XLA_FFI_Args`` and ``XLA_FFI_Rets``: ``size`` typed pointers."""

    _fields_ = [
        *_HEAD,
        ("size", ctypes.c_int64),
        ("types", ctypes.POINTER(ctypes.c_int)),
        ("items", ctypes.POINTER(ctypes.c_void_p)),
    ]


class _Attributes(ctypes.Structure):
    _fields_ = [
        *_HEAD,
        ("size", ctypes.c_int64),
        ("types", ctypes.POINTER(ctypes.c_int)),
        ("names", ctypes.POINTER(ctypes.c_void_p)),
        ("items", ctypes.POINTER(ctypes.c_void_p)),
    ]


class _CallFrame(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.POINTER(_Extension)),
        ("api", ctypes.c_void_p),
        ("ctx", ctypes.c_void_p),
        ("stage", ctypes.c_int),
        ("args", _Values),
        ("rets", _Values),
        ("attrs", _Attributes),
    ]


class _Buffer(ctypes.Structure):
    _fields_ = [
        *_HEAD,
        ("dtype", ctypes.c_int),
        ("data", ctypes.c_void_p),
        ("rank", ctypes.c_int64),
        ("dims", ctypes.POINTER(ctypes.c_int64)),
    ]


class _ByteSpan(ctypes.Structure):
    _fields_ = [("data", ctypes.c_void_p), ("size", ctypes.c_size_t)]


class _Scalar(ctypes.Structure):
    _fields_ = [("dtype", ctypes.c_int), ("value", ctypes.c_void_p)]


class _ErrorArguments(ctypes.Structure):
    _fields_ = [
        *_HEAD,
        ("message", ctypes.c_char_p),
        ("errc", ctypes.c_int),
    ]


_ErrorCreate = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorArguments))


class _Api(ctypes.Structure):
    """The head of ``XLA_FFI_Api``: its first function creates an error."""

    _fields_ = [
        *_HEAD,
        ("api_version", _Version),
        ("internal_api", ctypes.c_void_p),
        ("error_create", _ErrorCreate),
    ]


_Handler = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))
_registered: dict[str, tuple[HostFunction, _Handler]] = {}
"""The registered functions by target name, with the ctypes pointer XLA calls (kept alive here)."""
_lock = threading.Lock()


def register(name: str, function: HostFunction) -> None:
    """Make ``function`` the FFI target ``name`` of this process (CPU); registering a name again is a no-op.

    Raises:
        ValueError: ``name`` is registered with another function.
    """
    with _lock:
        if name in _registered:
            if _registered[name][0] is not function:
                raise ValueError(f"the FFI target {name!r} is registered with another function")
            return
        handler = _Handler(lambda frame: _handle(name, function, frame.contents))
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(handler), platform="cpu")
        if not _registered:
            threading._register_atexit(_finish_running_programs)
        _registered[name] = (function, handler)


def call(
    name: str, results: Sequence[jax.ShapeDtypeStruct], *inputs: jax.Array, **attributes: str | int
) -> tuple[jax.Array, ...]:
    """The registered function ``name`` on ``inputs`` inside a traced program, with ``attributes``.

    Under ``vmap`` the function receives the vmapped axes as leading axes of every input and result
    (``vmap_method="broadcast_all"``), as ``jax.pure_callback`` with that method does.

    Args:
        name: a target given to :func:`register` (in this process before the program runs).
        results: the results' shapes and dtypes for one call.
        inputs: arrays.
        attributes: strings and integers the function receives by name.
    """
    return tuple(jax.ffi.ffi_call(name, tuple(results), vmap_method="broadcast_all")(*inputs, **attributes))


def _finish_running_programs() -> None:
    """Wait for every computation whose results are alive (a failed one is left to its caller to report)."""
    for array in jax.live_arrays():
        try:
            array.block_until_ready()
        except RuntimeError:
            continue


def _handle(name: str, function: HostFunction, frame: _CallFrame) -> int | None:
    """XLA's call of target ``name``: the metadata answer, or ``function`` on the buffers at the execute
    stage; None (no error) or an XLA error."""
    if frame.extension_start and frame.extension_start.contents.type == METADATA_EXTENSION:
        metadata = ctypes.cast(frame.extension_start, ctypes.POINTER(_MetadataExtension)).contents.metadata
        metadata.contents.api_version.major, metadata.contents.api_version.minor = API_VERSION
        metadata.contents.traits = 0
        return None
    if frame.stage != EXECUTE:
        return None
    try:
        function(_arrays(frame.args), _arrays(frame.rets), _attributes(frame.attrs))
    except BaseException as error:  # every failure goes back to XLA, which raises it where the program runs
        message = f"{name}: {type(error).__name__}: {error}\n{traceback.format_exc()}"
        return _error(frame, message)
    return None


def _arrays(values: _Values) -> list[np.ndarray]:
    """The buffers of ``values`` as NumPy views of XLA's memory."""
    arrays = []
    for i in range(values.size):
        buffer = ctypes.cast(values.items[i], ctypes.POINTER(_Buffer)).contents
        dtype = np.dtype(DTYPES[buffer.dtype])
        shape = tuple(buffer.dims[d] for d in range(buffer.rank))
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        raw = (ctypes.c_char * size).from_address(buffer.data) if size else bytearray()
        arrays.append(np.frombuffer(raw, dtype).reshape(shape))
    return arrays


def _attributes(attributes: _Attributes) -> dict[str, str | int]:
    """The call's string and integer attributes by name."""
    found: dict[str, str | int] = {}
    for i in range(attributes.size):
        key = ctypes.cast(attributes.names[i], ctypes.POINTER(_ByteSpan)).contents
        name = ctypes.string_at(key.data, key.size).decode()
        if attributes.types[i] == STRING_ATTRIBUTE:
            span = ctypes.cast(attributes.items[i], ctypes.POINTER(_ByteSpan)).contents
            found[name] = ctypes.string_at(span.data, span.size).decode()
        elif attributes.types[i] == SCALAR_ATTRIBUTE:
            scalar = ctypes.cast(attributes.items[i], ctypes.POINTER(_Scalar)).contents
            dtype = np.dtype(DTYPES[scalar.dtype])
            found[name] = np.frombuffer(ctypes.string_at(scalar.value, dtype.itemsize), dtype)[0].item()
    return found


def _error(frame: _CallFrame, message: str) -> int:
    """An XLA error with ``message``, made by the API XLA passed in ``frame``."""
    api = ctypes.cast(frame.api, ctypes.POINTER(_Api)).contents
    arguments = _ErrorArguments(
        struct_size=_ErrorArguments.errc.offset + ctypes.sizeof(ctypes.c_int),
        message=message.encode(errors="replace"),
        errc=INTERNAL_ERROR,
    )
    return api.error_create(ctypes.byref(arguments))
