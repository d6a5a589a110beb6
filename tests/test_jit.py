"""numba's cache: where it cannot be written, the kernels still compile, with the fix named."""

from __future__ import annotations

import logging

import numba
import numba.core.caching as caching

from wholehand import jit


def test_no_writable_cache_folder_warns_and_compiles_without_a_cache(monkeypatch, caplog):
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # renamed in numba 0.61
    monkeypatch.setattr(impl, "_locator_classes", [])  # nowhere to write
    with caplog.at_level(logging.WARNING, logger="wholehand.jit"):
        assert jit.cache_writable() is False
    assert "Set NUMBA_CACHE_DIR to a writable folder" in caplog.text
    monkeypatch.undo()
    assert jit.cache_writable() is True


def test_fma_rounds_once():
    @numba.njit
    def fused(a: float, b: float, c: float) -> float:
        return jit.fma(a, b, c)

    e = 2.0**-30
    # (1 + e)(1 - e) - 1 = -e^2 exactly; a multiply rounded before the add gives 0.
    assert fused(1.0 + e, 1.0 - e, -1.0) == -(e**2)
    assert (1.0 + e) * (1.0 - e) - 1.0 == 0.0
    assert fused(3.0, 4.0, 5.0) == 17.0
