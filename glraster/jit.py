"""numba's ``njit`` for glraster's kernels: compiled once per machine where numba can keep
its on-disk cache, else once per process.

numba keeps a compiled kernel beside its source (``__pycache__``) or in the user's cache
folder. A read-only install run by a user without a writable home has neither (the
service's systemd unit: ``ProtectSystem=strict``, ``ProtectHome=yes``; a container's user
with no home), and ``numba.njit(cache=True)`` raises at import ("no locator available").
There the cache goes to a folder of the temp dir that only this user can write
(``$NUMBA_CACHE_DIR`` when the user set it, numba's own setting), or, when no such folder
can be had, the kernels are compiled in every process without one.
"""

from __future__ import annotations

import os
import stat
import tempfile

import numba

__all__ = ["njit"]


def njit(**options):
    """``numba.njit(cache=True, **options)`` as a decorator, falling back as above."""
    def decorate(function):
        try:
            return numba.njit(cache=True, **options)(function)
        except RuntimeError as exc:
            if "no locator available" not in str(exc):
                raise
        return numba.njit(cache=_temporary_cache(), **options)(function)
    return decorate


def _temporary_cache() -> bool:
    """Point numba at ``TMP/glraster-numba-UID`` (made 0700) when it has no cache folder
    yet; False when that folder cannot be used: not made, not writable, or not this user's
    alone (numba's cache files hold code it loads: another user's folder is not trusted),
    or when numba has a cache folder already and could not use it."""
    if numba.config.CACHE_DIR:
        return False
    folder = os.path.join(tempfile.gettempdir(), f"glraster-numba-{os.getuid()}")
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        info = os.lstat(folder)
    except OSError:
        return False
    if (not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid()
            or info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
            or not os.access(folder, os.W_OK)):
        return False
    # numba reads the setting when it looks for a cache, and again from the environment
    # when it reloads its configuration (as do the service's worker processes)
    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"] = folder
    return True
