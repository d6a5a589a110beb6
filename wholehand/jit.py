"""Whether the compiled kernels can keep numba's machine-code cache.

Kernels are compiled with ``cache=CACHE``. Numba writes its cache to ``$NUMBA_CACHE_DIR``, else
to ``__pycache__`` beside the module, else to the user's cache folder; where none is writable
(a read-only install run by a user without a home), ``cache=True`` would fail at import. Then
the kernels compile in every process instead (about 2 s at start-up), and a warning names the
fix.
"""

from __future__ import annotations

import logging

import numba

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
