"""NumPy ``.npy`` files read without running code from them.

Published grasp sets are ``.npy`` files of pickled Python objects (a dict, or a list of dicts,
saved with ``np.save``), and they are passed between labs. ``np.load(allow_pickle=True)`` would
let such a file call any Python function while it is read. :func:`load_npy` reads the same
files with an unpickler that builds only NumPy arrays, dtypes and scalars besides pickle's own
dicts, lists, tuples, numbers, strings and bytes; any other object a file asks for stops the
read before it is built, with an error naming it.
"""

from __future__ import annotations

import codecs
import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.errors import ConfigError

_NUMPY_CORE = ("numpy.core.multiarray", "numpy._core.multiarray")
_NUMPY_NUMERIC = ("numpy.core.numeric", "numpy._core.numeric")
ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {
    **{(m, "_reconstruct"): np.ndarray.__reduce__(np.zeros(0))[0] for m in _NUMPY_CORE},
    **{(m, "scalar"): np.float64(0).__reduce__()[0] for m in _NUMPY_CORE},
    **{(m, "_frombuffer"): np.zeros(1).__reduce_ex__(5)[0] for m in _NUMPY_NUMERIC},
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("_codecs", "encode"): codecs.encode,
}
"""The only callables and classes a grasp file may name: what ``np.save`` writes for arrays
(NumPy 1 and 2 module names), their dtypes and scalars, and protocol 2's bytes."""


class _ArraysOnly(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        try:
            return ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(f"{module}.{name}") from None


def load_npy(path: Path) -> Any:
    """The contents of the ``.npy`` file ``path``: an array, or for an object array the Python
    objects it holds (as ``np.load(path, allow_pickle=True)`` would give them).

    Raises:
        ConfigError: The file is not a ``.npy`` file, is cut short, or asks to build an object
            other than arrays, dicts, lists, tuples, numbers and strings (nothing of it was run).
    """
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            header = (
                np.lib.format.read_array_header_1_0
                if version == (1, 0)
                else np.lib.format.read_array_header_2_0
            )
            _, _, dtype = header(f)
            if not dtype.hasobject:
                return np.load(path, allow_pickle=False)
            body = f.read()
    except (OSError, ValueError, EOFError) as err:
        raise ConfigError(f"{path}: not a NumPy .npy file this reader can open ({err})") from err
    try:
        return _ArraysOnly(io.BytesIO(body), encoding="latin1").load()
    except pickle.UnpicklingError as err:
        raise ConfigError(
            f"{path}: the file asks to build the Python object {err}, which a grasp file never "
            "holds; it was not read and nothing in it was run. Grasp files hold only NumPy "
            "arrays, dicts, lists, numbers and strings: re-save the grasps as those"
        ) from None
    except Exception as err:  # a damaged pickle stream fails in many ways
        raise ConfigError(f"{path}: the .npy file's pickled data is damaged ({err!r})") from None
