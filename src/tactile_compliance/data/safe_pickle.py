"""Load pickled numpy arrays from untrusted dataset files without executing code or
allocating what the file merely declares (an allow-list unpickler, size checks before any
allocation, an opcode walk before unpickling), and write them as the dataset does.

See docs/data.md, "Untrusted pickles: what the loader refuses".
"""

from __future__ import annotations

import codecs
import io
import math
import operator
import pickle
import pickletools
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

#: Largest array a pickle may declare, in elements (64 Mi = 67,108,864). A full dataset
#: frame stack (3, 250, 350, 3) has 787,500; this leaves room for 85x larger frames.
MAX_ARRAY_ELEMENTS = 64 * 2**20
#: Largest array a pickle may declare, in bytes (512 MiB: 64 Mi float64 values).
MAX_ARRAY_BYTES = 8 * MAX_ARRAY_ELEMENTS
#: Largest pickle file read at all (1 GiB); larger files are rejected unread.
MAX_PICKLE_BYTES = 2 * MAX_ARRAY_BYTES
#: More opcodes than this is no numpy array pickle (those have fewer than 100).
MAX_PICKLE_OPCODES = 100_000

# numpy 2 moved numpy.core to numpy._core; files written by numpy 1.x name the old path.
_NUMPY_CORE_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")
_NUMPY_NUMERIC_MODULES = ("numpy.core.numeric", "numpy._core.numeric")


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle asked for something other than numpy arrays, scalars or dtypes."""


class ArrayTooLargeError(pickle.UnpicklingError):
    """The pickle declares an array (or file) beyond :data:`MAX_ARRAY_ELEMENTS` /
    :data:`MAX_ARRAY_BYTES` / :data:`MAX_PICKLE_BYTES`; nothing was allocated for it."""


def check_array_size(shape: Any, dtype: Any) -> None:
    """Raise :class:`ArrayTooLargeError` when an array of ``shape`` and ``dtype`` would
    exceed the limits (subarray dtypes count their elements too), and
    :class:`UnsafePickleError` when the shape or dtype cannot be read (fail closed)."""
    try:
        try:
            dims: tuple[int, ...] = (operator.index(shape),)
        except TypeError:
            dims = tuple(operator.index(d) for d in shape)
        dt = np.dtype(dtype)
    except (TypeError, ValueError) as err:
        raise UnsafePickleError(f"unreadable array shape or dtype ({err})") from None
    if any(d < 0 for d in dims):
        return  # numpy rejects negative dimensions itself, before allocating
    count = math.prod(dims)
    elements = count * math.prod(dt.shape)
    nbytes = count * dt.itemsize
    if elements > MAX_ARRAY_ELEMENTS or nbytes > MAX_ARRAY_BYTES:
        raise ArrayTooLargeError(
            f"declares an array of shape {dims} and dtype {dt} ({elements} elements, "
            f"{nbytes} bytes); the limit is {MAX_ARRAY_ELEMENTS} elements and "
            f"{MAX_ARRAY_BYTES} bytes"
        )


class _GuardedNdarray:
    """Stands for ``numpy.ndarray`` in a pickle: calling it checks the size first."""

    def __call__(self, shape: Any, dtype: Any = float, *args: Any, **kwargs: Any) -> np.ndarray:
        check_array_size(shape, dtype)
        return np.ndarray(shape, dtype, *args, **kwargs)


_NDARRAY = _GuardedNdarray()


def _allowed_globals() -> dict[tuple[str, str], Any]:
    try:
        from numpy._core import multiarray as core_multiarray
        from numpy._core import numeric as core_numeric
    except ImportError:  # numpy < 2
        from numpy.core import multiarray as core_multiarray  # type: ignore[no-redef]
        from numpy.core import numeric as core_numeric  # type: ignore[no-redef]

    def reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
        if subtype is not _NDARRAY:
            raise UnsafePickleError("refusing to rebuild an array of a type other than ndarray")
        check_array_size(shape, dtype)
        return core_multiarray._reconstruct(np.ndarray, shape, dtype)

    def scalar(dtype: Any, *args: Any) -> Any:
        check_array_size((), dtype)
        return core_multiarray.scalar(dtype, *args)

    def encode(obj: Any, encoding: str = "utf-8", errors: str = "strict") -> bytes:
        # Protocol-2 pickles encode raw bytes as a latin-1 str; no other codec is needed.
        if codecs.lookup(encoding).name != "iso8859-1":
            raise UnsafePickleError(f"refusing codec {encoding!r}: only latin-1 is allowed")
        return codecs.encode(obj, encoding, errors)

    allowed: dict[tuple[str, str], Any] = {
        ("numpy", "ndarray"): _NDARRAY,
        ("numpy", "dtype"): np.dtype,
        ("_codecs", "encode"): encode,
    }
    for module in _NUMPY_CORE_MODULES:
        allowed[(module, "_reconstruct")] = reconstruct
        allowed[(module, "scalar")] = scalar
    if hasattr(core_numeric, "_frombuffer"):

        def frombuffer(buffer: Any, dtype: Any, shape: Any, order: str = "C") -> np.ndarray:
            check_array_size(shape, dtype)
            return core_numeric._frombuffer(buffer, dtype, shape, order)

        for module in _NUMPY_NUMERIC_MODULES:
            allowed[(module, "_frombuffer")] = frombuffer
    # dtype classes such as numpy.dtypes.Float64DType appear in numpy 2 pickles.
    for name in dir(np.dtypes):
        if name.endswith("DType"):
            allowed[("numpy.dtypes", name)] = getattr(np.dtypes, name)
    return allowed


_ALLOWED = _allowed_globals()


class NumpyOnlyUnpickler(pickle.Unpickler):
    """An unpickler that can only rebuild numpy arrays, numpy scalars and dtypes, and only
    arrays within the size limits."""

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"refusing to load {module}.{name}: only numpy arrays and dtypes are allowed"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError("persistent references are not allowed")


# ------------------------------------------------------------------------ opcode walking
# Length prefixes of pickletools' counted arguments: (prefix bytes, signed).
_COUNTED = {
    pickletools.TAKEN_FROM_ARGUMENT1: (1, False),
    pickletools.TAKEN_FROM_ARGUMENT4: (4, True),
    pickletools.TAKEN_FROM_ARGUMENT4U: (4, False),
    pickletools.TAKEN_FROM_ARGUMENT8U: (8, False),
}
_SMALL_ARGUMENT = 4096  # counted arguments up to this size are decoded, larger ones skipped
_MEMO_PUTS = {"PUT", "BINPUT", "LONG_BINPUT"}


class _Bulk:
    """A large byte/str argument that was skipped, not read."""

    def __init__(self, length: int) -> None:
        self.length = length


def _opcodes(stream: IO[bytes], size: int, max_opcodes: int) -> Iterator[tuple[str, Any]]:
    """(opcode name, argument) of a pickle stream, checking every declared length against
    the ``size`` bytes of the stream; arguments over 4 KiB are skipped (:class:`_Bulk`)."""
    for count in range(max_opcodes):
        code = stream.read(1)
        if not code:
            raise pickle.UnpicklingError("pickle data was truncated")
        op = pickletools.code2op.get(code.decode("latin-1"))
        if op is None:
            raise pickle.UnpicklingError(f"invalid pickle opcode {code!r}")
        arg: Any = None
        descriptor = op.arg
        if descriptor is not None and descriptor.n in _COUNTED:
            prefix_size, signed = _COUNTED[descriptor.n]
            start = stream.tell()
            prefix = stream.read(prefix_size)
            length = int.from_bytes(prefix, "little", signed=signed)
            remaining = size - start - prefix_size
            if len(prefix) < prefix_size or length < 0 or length > remaining:
                raise pickle.UnpicklingError(
                    f"{op.name} declares {length} bytes but only {max(remaining, 0)} remain"
                )
            if length > _SMALL_ARGUMENT:
                stream.seek(length, io.SEEK_CUR)
                arg = _Bulk(length)
            else:
                stream.seek(start)
                arg = descriptor.reader(stream)
        elif descriptor is not None:
            arg = descriptor.reader(stream)
            if op.name == "FRAME" and arg > size - stream.tell():
                raise pickle.UnpicklingError(f"FRAME declares {arg} bytes beyond the file")
            if op.name in _MEMO_PUTS and arg > count:
                raise pickle.UnpicklingError(f"memo index {arg} out of range")
        yield op.name, arg
        if op.name == "STOP":
            return
    raise pickle.UnpicklingError(f"more than {max_opcodes} opcodes: not a numpy array pickle")


def check_pickle_stream(data: bytes) -> None:
    """Walk a whole pickle without building anything; raise ``pickle.UnpicklingError`` for
    a declared length beyond the data, an out-of-range memo index or too many opcodes
    (each would make the unpickler reserve memory the file does not hold)."""
    for _ in _opcodes(io.BytesIO(data), len(data), MAX_PICKLE_OPCODES):
        pass


_MARK = object()
_PUSH_ARGUMENT = {
    "INT",
    "BININT",
    "BININT1",
    "BININT2",
    "LONG",
    "LONG1",
    "LONG4",
    "STRING",
    "BINSTRING",
    "SHORT_BINSTRING",
    "UNICODE",
    "BINUNICODE",
    "SHORT_BINUNICODE",
    "BINUNICODE8",
    "BINBYTES",
    "SHORT_BINBYTES",
    "BINBYTES8",
    "BYTEARRAY8",
    "FLOAT",
    "BINFLOAT",
}
_CONSTANTS = {"NONE": None, "NEWTRUE": True, "NEWFALSE": False, "EMPTY_TUPLE": ()}


def _is_int_tuple(value: Any) -> bool:
    return isinstance(value, tuple) and all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    )


def peek_array_shape(path: str | Path, max_opcodes: int = 300) -> tuple[int, ...] | None:
    """The shape a numpy array pickle declares, read from its first opcodes without loading
    the data (a few hundred bytes for protocols 0-4; protocol 5 skips over the data);
    None when the file is not laid out like a pickled ndarray or is unreadable.

    Only a hint (the importer's frame-size vote): the file may still fail to load.
    """
    stack: list[Any] = []
    memo: dict[int, Any] = {}
    try:
        with open(path, "rb") as stream:
            size = Path(path).stat().st_size
            for name, arg in _opcodes(stream, size, max_opcodes):
                if name in ("PROTO", "FRAME"):
                    continue
                if name == "MARK":
                    stack.append(_MARK)
                elif name in _PUSH_ARGUMENT:
                    stack.append(arg)
                elif name in _CONSTANTS:
                    stack.append(_CONSTANTS[name])
                elif name == "GLOBAL":
                    stack.append(("global", *str(arg).split(" ", 1)))
                elif name == "STACK_GLOBAL":
                    attribute, module = stack.pop(), stack.pop()
                    stack.append(("global", module, attribute))
                elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
                    n = int(name[-1])
                    items = tuple(stack[-n:])
                    del stack[-n:]
                    stack.append(items)
                elif name == "TUPLE":
                    mark = len(stack) - 1 - stack[::-1].index(_MARK)
                    items = tuple(stack[mark + 1 :])
                    del stack[mark:]
                    stack.append(items)
                elif name == "MEMOIZE":
                    memo[len(memo)] = stack[-1]
                elif name in _MEMO_PUTS:
                    memo[arg] = stack[-1]
                elif name in ("GET", "BINGET", "LONG_BINGET"):
                    stack.append(memo[arg])
                elif name == "REDUCE":
                    args, function = stack.pop(), stack.pop()
                    if (
                        isinstance(function, tuple)
                        and function[1:] in [(m, "_frombuffer") for m in _NUMPY_NUMERIC_MODULES]
                        and isinstance(args, tuple)
                        and len(args) >= 3
                        and _is_int_tuple(args[2])
                    ):
                        return args[2]  # protocol 5: _frombuffer(data, dtype, shape, order)
                    stack.append(("call", function, args))
                elif name == "BUILD":
                    stack.pop()
                else:
                    return None
                # Protocols 0-4: _reconstruct(ndarray, (0,), b) then BUILD (1, shape, ...).
                if (
                    len(stack) >= 4
                    and _is_int_tuple(stack[-1])
                    and stack[-2] == 1
                    and stack[-3] is _MARK
                    and isinstance(stack[-4], tuple)
                    and stack[-4][:1] == ("call",)
                    and stack[-4][1][1:] in [(m, "_reconstruct") for m in _NUMPY_CORE_MODULES]
                ):
                    return stack[-1]  # type: ignore[no-any-return]
    except (OSError, pickle.UnpicklingError, ValueError, IndexError, KeyError, TypeError):
        return None
    return None


def load_numpy_pickle(path: str | Path) -> np.ndarray:
    """Read a pickled numpy array (or scalar, returned as a 0-d array) safely.

    Raises :class:`UnsafePickleError` for anything but numpy content,
    :class:`ArrayTooLargeError` for an array or file over the size limits (before
    allocating it), and ``pickle.UnpicklingError``/``EOFError``/``ValueError`` for
    truncated or corrupt files.
    """
    size = Path(path).stat().st_size
    if size > MAX_PICKLE_BYTES:
        raise ArrayTooLargeError(f"file is {size} bytes; the limit is {MAX_PICKLE_BYTES} bytes")
    data = Path(path).read_bytes()
    check_pickle_stream(data)
    result = NumpyOnlyUnpickler(io.BytesIO(data)).load()
    if isinstance(result, np.generic):
        return np.asarray(result)
    if not isinstance(result, np.ndarray):
        raise UnsafePickleError(f"{path}: expected a numpy array, found {type(result).__name__}")
    if result.dtype.hasobject:
        raise UnsafePickleError(f"{path}: object arrays are not allowed")
    return result


PICKLE_PROTOCOL = 4
"""Protocol of the pickles written (same bytes for the same array)."""


def dump_numpy_pickle(path: str | Path, array: np.ndarray) -> None:
    """Write ``array`` as a pickled numpy array, the dataset's ``.pkl`` format.

    C order is required without ``np.ascontiguousarray``, which would turn a 0-d
    estimate into shape (1,). The file is created new (``"xb"``: never over a file, never
    through a link): the writers fill a temporary directory they have just created and
    commit it whole (``outputs.commit_path``).
    """
    with open(path, "xb") as handle:
        pickle.dump(np.require(array, requirements="C"), handle, protocol=PICKLE_PROTOCOL)


class UnreadableTorchFileError(ValueError):
    """A file ``torch.load(weights_only=True)`` cannot read, with the reason in one line
    (``reason``: the part after the file name)."""

    def __init__(self, path: Path, what: str, reason: str) -> None:
        super().__init__(f"{path}: not a readable {what}: {reason}")
        self.reason = reason


def load_torch_file(path: str | Path, what: str, *, map_location: Any = "cpu") -> Any:
    """``torch.load(path, weights_only=True)`` (never executes pickled code), whose errors
    say in one line what the file is instead of torch's several lines, which end by
    advising ``weights_only=False``, the unsafe load this project never does.

    Args:
        what: what the caller expected, for the message ("checkpoint", "backbone weights").

    Raises:
        UnreadableTorchFileError: not a file of ``torch.save``, a damaged one, or one that
            holds Python objects beyond tensors and plain containers.
    """
    import torch

    path = Path(path)
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # torch raises several types for foreign or damaged files
        raise UnreadableTorchFileError(path, what, torch_file_problem(path, err)) from err


def torch_file_problem(path: Path, err: BaseException) -> str:
    """Why a file did not load (one line, never torch's advice to load it unsafely), from
    its first bytes and torch's error."""
    with open(path, "rb") as handle:
        start = handle.read(64)
    # "ignore": the 64 bytes may end inside a character; binary bytes leave control
    # characters, which fail the test below.
    text = start.decode("utf-8", errors="ignore")
    if text.strip() and all(c.isprintable() or c in "\r\n\t" for c in text):
        first = text.strip().splitlines()[0][:40]
        return f"a text file (it starts with {first!r}), not a file written by torch.save"
    if "weights_only" in str(err) or "WeightsUnpickler" in str(err):
        return (
            "it holds Python objects other than tensors and plain containers, which the "
            "safe load refuses (tactile-compliance never writes such files)"
        )
    if not start.startswith(b"PK"):  # torch.save writes a zip archive
        return "not a file written by torch.save (not a zip archive)"
    lines = [line for line in str(err).splitlines() if line.strip()]
    return f"a damaged or incomplete torch file ({lines[0] if lines else type(err).__name__})"
