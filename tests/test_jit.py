"""Compiled kernels: cached in the user's cache folder (never beside the modules), compiled
anyway where no cache can be written, and the first compile told."""

from pathlib import Path

import numba
import numba.core.caching as caching
import pytest

import milestones.jit as jit
from vmp.jit import kernel


@pytest.fixture
def folder(monkeypatch, tmp_path):
    """Kernels declared in the test are cached in a folder of its own."""
    monkeypatch.setattr(jit, "_FOLDER", (tmp_path / "kernels", True))
    (tmp_path / "kernels").mkdir()
    return tmp_path / "kernels"


def test_a_kernel_is_cached_in_the_cache_folder_and_numba_left_as_it_was(folder):
    before = numba.config.CACHE_DIR

    def thrice(x):
        return 3 * x

    compiled = kernel(thrice)
    assert numba.config.CACHE_DIR == before  # other Numba users keep their cache folder
    assert compiled(14) == 42
    assert any(p.suffix == ".nbi" for p in folder.rglob("*"))  # the index of the cache
    assert not list(Path(__file__).parent.glob("__pycache__/*.nbi"))  # nothing beside us


def test_a_kernel_with_nowhere_to_cache_still_runs(monkeypatch, tmp_path):
    monkeypatch.setattr(jit, "_FOLDER", (tmp_path / "kernels", False))

    def twice(x):
        return 2 * x

    compiled = kernel(twice)
    assert compiled(21) == 42
    assert isinstance(compiled._cache, caching.NullCache)
    assert not list(tmp_path.rglob("*.nbi"))


def test_a_kernel_numba_cannot_cache_still_runs(monkeypatch, folder):
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])

    def twice(x):
        return 2 * x

    with pytest.raises(RuntimeError, match="no locator"):  # what the fallback is for
        numba.njit(cache=True)(twice)
    assert kernel(twice)(21) == 42


def test_the_cache_folder_is_the_users_unless_an_environment_variable_names_one(
        monkeypatch, tmp_path):
    for name in (jit.CACHE_ENV, "NUMBA_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if jit.sys.platform.startswith("linux"):
        assert jit._chosen_folder() == tmp_path / "xdg" / "vmp-slam" / "kernels"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert jit._chosen_folder() == tmp_path / "numba"
    monkeypatch.setenv(jit.CACHE_ENV, str(tmp_path / "ours"))
    assert jit._chosen_folder() == tmp_path / "ours"


def test_a_folder_that_cannot_be_made_is_not_writable(tmp_path):
    (tmp_path / "a-file").write_text("")  # a file where the folder would go (root ignores modes)
    assert not jit._writable(tmp_path / "a-file" / "kernels")
    assert jit._writable(tmp_path / "fine" / "kernels")


def test_the_first_compile_is_told_once_with_the_folder_and_its_time_counted(monkeypatch,
                                                                               folder):
    told: list[str] = []
    monkeypatch.setattr(jit._CLOCK, "told", False)
    jit.on_first_compile(told.append)
    try:
        before = jit.compile_seconds()

        @kernel
        def plus_one(x):
            return x + 1

        @kernel
        def plus_two(x):
            return x + 2

        assert plus_one(1) == 2 and plus_two(1) == 3
    finally:
        jit.on_first_compile(None)
    assert told == [f"compiling kernels once, cached in {folder} (the first run after an "
                    "install takes longer)"]
    assert jit.compile_seconds() > before
    assert not jit.compiling()
