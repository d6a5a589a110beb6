"""Shared pieces of the compiled kernels: whether numba can keep its machine-code cache, and a
fused multiply-add.

Kernels are compiled with ``cache=CACHE``. Numba writes its cache to ``$NUMBA_CACHE_DIR``, else
to ``__pycache__`` beside the module, else to the user's cache folder; where none is writable
(a read-only install run by a user without a home), ``cache=True`` would fail at import. Then
the kernels compile in every process instead (about 2 s at start-up), and a warning names the
fix.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, cast

import numba
from numba import types
from numba.extending import intrinsic

log = logging.getLogger(__name__)


def _probe() -> int:
    return 0


def cache_writable() -> bool:
    """True when numba can cache functions of this package; else a warning and False."""
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError as err:  # numba: "cannot cache function ...: no locator available"
        log.warning(
            "numba cannot write its compilation cache (%s); wholehand's kernels will compile in "
            "every process (about 2 s). Set NUMBA_CACHE_DIR to a writable folder to keep it.",
            err,
        )
        return False
    return True


CACHE: bool = cache_writable()
"""``cache=`` of every ``numba.njit`` in wholehand."""


def _fma_typing(typingctx: Any, a: Any, b: Any, c: Any) -> Any:  # pragma: no cover - jit
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(*args)

    return sig, codegen


fma = cast(Callable[[float, float, float], float], intrinsic(_fma_typing))
"""``a * b + c`` rounded once (LLVM's ``llvm.fma.f64``), for float64 arguments; jit code only."""
