"""glraster.jit: where numba has no cache folder (a read-only install, no writable home)
the kernels still import and compile, cached in a temp-dir folder only this user can
write, or without a cache when that folder cannot be trusted. The real case (the
installed package run as another user with HOME=/nonexistent) was run by hand: first
`glraster check` 12.3 s, compiling into the folder, the next 1.4 s."""

from __future__ import annotations

import os

import numba
import numpy as np
import pytest
from numba.core import caching

from glraster import jit


@pytest.fixture
def no_cache_folder(monkeypatch, tmp_path):
    """numba with only $NUMBA_CACHE_DIR to cache in, and that unset (as for a read-only
    source tree and home), the temp dir at tmp_path; numba's setting restored after."""
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes",
                        [caching.UserProvidedCacheLocator])
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(jit.tempfile, "gettempdir", lambda: str(tmp_path))
    return tmp_path / f"glraster-numba-{os.getuid()}"


def _kernel(x):
    return x * 2.0 + 1.0


def test_without_a_cache_folder_kernels_cache_in_the_users_temp_folder(no_cache_folder):
    with pytest.raises(RuntimeError, match="no locator available"):
        numba.njit(cache=True)(_kernel)         # what glraster's kernels met before
    compiled = jit.njit(nogil=True)(_kernel)
    assert compiled(np.arange(3.0)).tolist() == [1.0, 3.0, 5.0]
    assert no_cache_folder.is_dir() and oct(no_cache_folder.stat().st_mode & 0o777) == "0o700"
    assert any(no_cache_folder.rglob("*.nbi")), "the compiled kernel was cached there"
    assert os.environ["NUMBA_CACHE_DIR"] == str(no_cache_folder)   # for worker processes


def test_a_temp_folder_others_can_write_is_not_trusted(no_cache_folder):
    no_cache_folder.mkdir()
    no_cache_folder.chmod(0o777)                # (another user could plant cache files)
    compiled = jit.njit(nogil=True)(_kernel)
    assert compiled(np.arange(3.0)).tolist() == [1.0, 3.0, 5.0]
    assert not any(no_cache_folder.iterdir()), "compiled without a cache"
    assert numba.config.CACHE_DIR == ""


def test_a_cache_folder_numba_cannot_use_means_no_cache(no_cache_folder, monkeypatch, tmp_path):
    """$NUMBA_CACHE_DIR set, yet numba found no locator (the folder is unusable): compiled
    without a cache, not retried into the same error."""
    monkeypatch.setattr(caching.UserProvidedCacheLocator, "from_function",
                        classmethod(lambda cls, py_func, py_file: None))
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "unusable"))
    compiled = jit.njit(nogil=True)(_kernel)
    assert compiled(np.arange(3.0)).tolist() == [1.0, 3.0, 5.0]
    assert not (tmp_path / "unusable").exists() and not no_cache_folder.exists()
