"""Uploads skipped when a buffer already holds the bytes: keys for input arrays, given by a
front end.

A front end that knows when an array last changed declares the arrays of an op call, each
with a *key*, for the duration of the call (:meth:`UploadCache.declare`; glraster.torch's
key names the tensor, its address, torch's version counter, shape and dtype).
:meth:`glraster.gpu.context.Context.storage_buffer` asks its cache (:meth:`UploadCache.held`)
before it writes: when the bytes to upload are exactly a declared array (the same address
and size) and some buffer of the context last received that array under the same key,
that buffer is returned and nothing is written. Data that nobody declared (every JAX call,
every array a core computes) is always uploaded.

The promise a key makes: equal keys, equal bytes. A key comes with an *owner* (held
weakly: the tensor whose memory it is); an entry whose owner was collected never matches,
so memory freed and reused by another array is uploaded afresh. What a key cannot see, it
cannot promise: a write that bypasses the front end's version counter (for torch: through
a NumPy view or ``.data``) leaves a stale buffer in place.

Only buffers that shaders read are cached this way: :meth:`UploadCache.forget` drops a
buffer's entry (a shader may write it: ``Context.scratch_buffer``), and an entry is
replaced by every write.

A buffer a shader wrote can also hold a declared array: an output a core read back whole
from it (rasterize's rast), whose bytes are then the buffer's. The core says so
(:meth:`UploadCache.produced`, the array's region); once the front end knows the output by
its key (:meth:`UploadCache.adopt`, before anything else writes the buffer), the buffer
holds that key as if it had been uploaded, and the next op reading the array binds it
instead of uploading the same bytes again.
"""

from __future__ import annotations

import ctypes
from contextlib import contextmanager

import numpy as np

__all__ = ["UploadCache"]


class UploadCache:
    """Which declared array each buffer of one context holds.

    ``skipped``, ``written``: counts of :meth:`held` hits and of keyed writes (tests).
    """

    def __init__(self):
        self._declared: dict = {}   # (address, nbytes) -> (key, owner ref), during calls
        self._sizes: dict = {}      # nbytes -> number of declared regions of that size
        self._holds: dict = {}      # buffer name -> (key, owner ref) of its bytes
        self._where: dict = {}      # key -> buffer name
        self._made: dict = {}       # buffer name -> region read back whole from it (no key)
        self.skipped = 0
        self.written = 0

    def declare(self, entries) -> list:
        """Know the arrays of ``entries`` by their key until :meth:`undeclare` of the list
        returned. An entry is ``(region, key, owner)``: ``region`` = (address, nbytes) of a
        C-contiguous array, ``key`` hashable, ``owner`` a weak reference to the object
        whose memory it is; a None entry, or one of no bytes, is left out. A region
        declared already (an enclosing call) keeps its key. What :meth:`produced` said
        before and no :meth:`adopt` took is dropped: only a region the call now starting
        produces can be adopted after it (memory freed since may hold another array)."""
        self._made.clear()
        added = []
        for entry in entries:
            if entry is not None and entry[0][1] and entry[0] not in self._declared:
                self._declared[entry[0]] = entry[1:]
                self._sizes[entry[0][1]] = self._sizes.get(entry[0][1], 0) + 1
                added.append(entry[0])
        return added

    def undeclare(self, added: list) -> None:
        for region in added:
            del self._declared[region]
            self._sizes[region[1]] -= 1
            if not self._sizes[region[1]]:
                del self._sizes[region[1]]

    @contextmanager
    def declared(self, entries):
        """:meth:`declare` for the block."""
        added = self.declare(entries)
        try:
            yield
        finally:
            self.undeclare(added)

    def lookup(self, data: np.ndarray):
        """The declared ``(key, owner)`` of ``data`` (C-contiguous), or None."""
        nbytes = data.nbytes
        flags = data.flags
        if nbytes not in self._sizes or not flags.c_contiguous:  # (the address: 1 us or more)
            return None
        # (ndarray.ctypes builds a ctypes object, 2 to 4 us; a ctypes view of a writable
        # array's buffer gives the same address in under 1)
        address = ctypes.addressof(ctypes.c_char.from_buffer(data)) if flags.writeable \
            else data.ctypes.data
        return self._declared.get((address, nbytes))

    def held(self, entry) -> str | None:
        """The name of a buffer holding the bytes of ``entry`` (from :meth:`lookup`), or
        None."""
        key = entry[0]
        name = self._where.get(key)
        holds = self._holds.get(name) if name is not None else None
        # (keys compared, never owners: a tensor's == is elementwise)
        if holds is None or holds[0] != key or holds[1]() is None:
            return None
        self.skipped += 1
        return name

    def wrote(self, name: str, entry) -> None:
        """Buffer ``name`` received the bytes of ``entry`` (None: of undeclared data)."""
        self._hold(name, entry)
        if entry is not None:
            self.written += 1

    def _hold(self, name: str, entry) -> None:
        """Buffer ``name`` now holds ``entry`` ``(key, owner)`` (None: undeclared bytes)."""
        self._made.pop(name, None)
        old = self._holds.pop(name, None)
        if old is not None and self._where.get(old[0]) == name:
            del self._where[old[0]]
        if entry is not None:
            self._holds[name] = entry
            self._where[entry[0]] = name

    def produced(self, name: str, region) -> None:
        """Buffer ``name`` (a shader's output) holds exactly the bytes now at ``region``
        (address, nbytes): a core's output array, read back whole from it, that nothing
        has written since; :meth:`adopt` gives the buffer that array's key."""
        self._made[name] = region

    def adopt(self, entry) -> bool:
        """The array of ``entry`` ``(region, key, owner)`` (a front end's key for a core's
        output, made just now) is held by the buffer that :meth:`produced` it, if any and
        not written since: that buffer then holds ``entry`` as if uploaded (not counted in
        ``written``). True when one did."""
        if entry is None:
            return False
        for name, region in self._made.items():
            if region == entry[0]:
                self._hold(name, entry[1:])
                return True
        return False

    def forget(self, name: str) -> None:
        """Buffer ``name`` may now hold anything (a shader writes it, or it was remade)."""
        self.wrote(name, None)

    def clear(self) -> None:
        self._made.clear()
        self._holds.clear()
        self._where.clear()
