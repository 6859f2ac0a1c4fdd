"""Compiled kernels: cached where a cache can be written, compiled anyway where none can."""

import numba
import numba.core.caching as caching
import pytest

from vmp.jit import kernel


def test_a_kernel_with_nowhere_to_cache_still_runs(monkeypatch):
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])

    def twice(x):
        return 2 * x

    with pytest.raises(RuntimeError, match="no locator"):  # what the fallback is for
        numba.njit(cache=True)(twice)
    assert kernel(twice)(21) == 42


def test_a_kernel_is_cached_where_it_can_be(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(caching.config, "CACHE_DIR", str(tmp_path))

    def thrice(x):
        return 3 * x

    assert kernel(thrice)(14) == 42
    assert any(p.suffix == ".nbi" for p in tmp_path.rglob("*"))  # the index of the cache
