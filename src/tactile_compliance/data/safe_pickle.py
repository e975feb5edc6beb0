"""Load pickled numpy arrays from untrusted dataset files without executing code.

Unpickling calls whatever callables the file names, so a crafted ``.pkl`` can run
arbitrary code. The dataset's pickles only ever contain numpy arrays, numpy scalars
and dtypes, so :class:`NumpyOnlyUnpickler` resolves exactly the handful of globals
numpy needs to rebuild those and rejects everything else *before* it is called.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np

# numpy 2 moved numpy.core to numpy._core; files written by numpy 1.x name the old path.
_NUMPY_CORE_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")
_NUMPY_NUMERIC_MODULES = ("numpy.core.numeric", "numpy._core.numeric")


def _allowed_globals() -> dict[tuple[str, str], Any]:
    import codecs

    try:
        from numpy._core import multiarray as core_multiarray
        from numpy._core import numeric as core_numeric
    except ImportError:  # numpy < 2
        from numpy.core import multiarray as core_multiarray  # type: ignore[no-redef]
        from numpy.core import numeric as core_numeric  # type: ignore[no-redef]

    allowed: dict[tuple[str, str], Any] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        # Protocol-2 pickles of numpy scalars encode raw bytes through codecs.encode,
        # which only converts a str to bytes.
        ("_codecs", "encode"): codecs.encode,
    }
    for module in _NUMPY_CORE_MODULES:
        allowed[(module, "_reconstruct")] = core_multiarray._reconstruct
        allowed[(module, "scalar")] = core_multiarray.scalar
    for module in _NUMPY_NUMERIC_MODULES:
        if hasattr(core_numeric, "_frombuffer"):
            allowed[(module, "_frombuffer")] = core_numeric._frombuffer
    # dtype classes such as numpy.dtypes.Float64DType appear in numpy 2 pickles.
    for name in dir(np.dtypes):
        if name.endswith("DType"):
            allowed[("numpy.dtypes", name)] = getattr(np.dtypes, name)
    return allowed


_ALLOWED = _allowed_globals()


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle asked for something other than numpy arrays, scalars or dtypes."""


class NumpyOnlyUnpickler(pickle.Unpickler):
    """An unpickler that can only rebuild numpy arrays, numpy scalars and dtypes."""

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"refusing to load {module}.{name}: only numpy arrays and dtypes are allowed"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError("persistent references are not allowed")


def load_numpy_pickle(path: str | Path) -> np.ndarray:
    """Read a pickled numpy array (or scalar, returned as a 0-d array) safely.

    Raises :class:`UnsafePickleError` for anything but numpy content, and
    ``pickle.UnpicklingError``/``EOFError``/``ValueError`` for truncated or corrupt files.
    """
    data = Path(path).read_bytes()
    result = NumpyOnlyUnpickler(io.BytesIO(data)).load()
    if isinstance(result, np.generic):
        return np.asarray(result)
    if not isinstance(result, np.ndarray):
        raise UnsafePickleError(f"{path}: expected a numpy array, found {type(result).__name__}")
    if result.dtype == object:
        raise UnsafePickleError(f"{path}: object arrays are not allowed")
    return result
