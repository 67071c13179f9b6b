"""Shared-memory cells for large results, between the server and one worker.

A 34.6 MB ``.npz`` result through the worker's pipe costs a kernel copy on each side (about
a fifth of the CPU of a 1024x1024 request on two cores). Instead, the server assigns a job
that asks for ``.npz`` one of ``CELLS`` cells of a memory file both processes map; the
worker writes the archive straight into it and answers with its length; the server
answers the HTTP request from that memory (no copy in the server at all) and takes the
cell back when nothing references the response's bytes any more (``weakref.finalize`` on
the array the response holds, so a slow client keeps its cell and nobody else's). With no
free cell, or a result below ``MIN_BYTES`` or above ``CELL_BYTES``, the result goes
through the pipe as before.

A cell belongs to one job from the moment it is sent until its answer has been read (or
its worker is gone), then to the response; only this slot's worker ever writes into its
cells, and a replacement worker maps the same file.
"""

from __future__ import annotations

import mmap
import os
import weakref
from multiprocessing import reduction

import numpy as np

CELLS = 4                 # cells per worker: one being written, the rest being sent
CELL_BYTES = 64 << 20     # the largest result a cell holds (1024x1024, every output: 34.6 MB)
MIN_BYTES = 1 << 20       # below this the pipe is as cheap


class SharedFile:
    """A file descriptor that a spawned worker inherits (pickled through multiprocessing's
    fd passing while the worker is started)."""

    def __init__(self, fd: int):
        self.fd = fd

    def __reduce__(self):
        return _rebuild, (reduction.DupFd(self.fd),)


def _rebuild(dup) -> SharedFile:
    return SharedFile(dup.detach())


class Arena:
    """The server's side: the memory file, its mapping and the free cells."""

    def __init__(self):
        self.fd = os.memfd_create("glraster-results", os.MFD_CLOEXEC)
        os.ftruncate(self.fd, CELLS * CELL_BYTES)    # sparse: a page costs once written
        self._map = mmap.mmap(self.fd, CELLS * CELL_BYTES)
        self._free = list(range(CELLS))

    def shared(self) -> SharedFile:
        return SharedFile(self.fd)

    def take(self) -> int | None:
        """A free cell, or None."""
        return self._free.pop() if self._free else None

    def give_back(self, cell: int) -> None:
        self._free.append(cell)

    @property
    def free(self) -> int:
        return len(self._free)

    def result(self, cell: int, nbytes: int) -> memoryview:
        """The ``nbytes`` a worker wrote into ``cell``, as a view the HTTP response sends;
        the cell is free again when the last reference to it has gone."""
        if not 0 < nbytes <= CELL_BYTES:
            self.give_back(cell)
            raise ValueError(f"a worker reported {nbytes} bytes in a cell of {CELL_BYTES}")
        array = np.frombuffer(self._map, np.uint8, count=nbytes, offset=cell * CELL_BYTES)
        weakref.finalize(array, self.give_back, cell)
        return memoryview(array)


class WorkerCells:
    """The worker's side: the same file, mapped; a cell as a writable uint8 array."""

    def __init__(self, shared: SharedFile):
        self._map = mmap.mmap(shared.fd, CELLS * CELL_BYTES)
        os.close(shared.fd)

    def cell(self, index: int) -> np.ndarray:
        return np.frombuffer(self._map, np.uint8, count=CELL_BYTES, offset=index * CELL_BYTES)
