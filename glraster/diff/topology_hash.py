"""The topology hash of a triangle mesh: its edges and, per edge, the triangles on either
side (NumPy only, no GL), which the antialias op walks across (docs/differentiable.md,
"Antialias"; Laine et al. 2020). Both antialias cores read it; the GPU probes
:meth:`TopologyHash.table`, an open-addressing hash table of the edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError

__all__ = ["HASH_EMPTY", "TopologyHash", "antialias_construct_topology_hash",
           "topology_hash_for"]

HASH_EMPTY = 0xFFFFFFFF
_MASK32 = 0xFFFFFFFF
_HASH_A = 0x9E3779B1
_HASH_B = 0x85EBCA77


def _hash(lo: np.ndarray, hi: np.ndarray, mask: int) -> np.ndarray:
    """The slot of edge (lo, hi), lo <= hi, in a table of mask + 1 slots: the GPU's
    ``(lo * 0x9E3779B1) ^ (hi * 0x85EBCA77)`` in uint32 arithmetic, then ``^ (h >> 15)``."""
    lo = lo.astype(np.uint64)
    hi = hi.astype(np.uint64)
    h = ((lo * _HASH_A) & _MASK32) ^ ((hi * _HASH_B) & _MASK32)
    h ^= h >> np.uint64(15)
    return (h & np.uint64(mask)).astype(np.int64)


# --------------------------------------------------------------------------- topology hash


@dataclass(frozen=True, eq=False)
class TopologyHash:
    """The edges of a triangle mesh and, per edge, the vertices opposite it.

    tri       : (T, 3) int32, the triangles it was built from
    canon     : (V,) int64, each vertex's representative (itself unless welded)
    keys      : (E,) int64 sorted, lo * V + hi of the canonical edge (lo <= hi)
    start, count : (E,) int64, each edge's run in ``entries``
    entries   : (3T,) int32, 3 t + i for each triangle t having the edge as its edge i
                (the one opposite its vertex i: ``tri.ravel()[entry]`` is that vertex),
                grouped by edge
    welded    : whether vertices at equal positions were merged
    """

    tri: np.ndarray
    canon: np.ndarray
    keys: np.ndarray
    start: np.ndarray
    count: np.ndarray
    entries: np.ndarray
    welded: bool = False
    _table: list = field(default_factory=list, repr=False)

    @property
    def num_vertices(self) -> int:
        return len(self.canon)

    @property
    def num_edges(self) -> int:
        return len(self.keys)

    @property
    def opposite(self) -> np.ndarray:
        """(3T,) the vertex opposite the edge in each of ``entries``."""
        return self.tri.ravel()[self.entries]

    def lookup(self, a, b) -> tuple[np.ndarray, np.ndarray]:
        """(start, count) of the edges (a, b) (arrays of vertex indices; count 0 where the
        edge is not in the mesh)."""
        ca, cb = self.canon[np.asarray(a)], self.canon[np.asarray(b)]
        key = np.minimum(ca, cb) * self.num_vertices + np.maximum(ca, cb)
        at = np.clip(np.searchsorted(self.keys, key), 0, max(len(self.keys) - 1, 0))
        found = (self.keys[at] == key) if len(self.keys) else np.zeros(key.shape, bool)
        return np.where(found, self.start[at], 0), np.where(found, self.count[at], 0)

    def table(self) -> np.ndarray:
        """The open-addressing hash table the GPU probes: (S, 4) uint32 rows
        (lo, hi, start, count), S a power of two >= 2 E, lo = 0xffffffff on empty slots;
        edge (lo, hi) sits at the first free slot from ``_hash(lo, hi)`` on (linear
        probing), so a lookup probes until it finds the key or an empty slot."""
        if self._table:
            return self._table[0]
        edges = len(self.keys)
        size = 1 << max(4, int(2 * max(edges, 1) - 1).bit_length())
        mask = size - 1
        lo, hi = self.keys // self.num_vertices, self.keys % self.num_vertices
        slot_of = _hash(lo, hi, mask)
        owner = np.full(size, -1, np.int64)
        pending = np.arange(edges)
        probe = slot_of.copy()
        while pending.size:
            want = probe[pending]
            free = owner[want] < 0
            cand, slots = pending[free], want[free]
            slots_u, first = np.unique(slots, return_index=True)
            owner[slots_u] = cand[first]
            placed = np.zeros(edges, bool)
            placed[cand[first]] = True
            pending = pending[~placed[pending]]
            probe[pending] = (probe[pending] + 1) & mask
        table = np.zeros((size, 4), np.uint32)
        table[:, 0] = HASH_EMPTY
        used = owner >= 0
        e = owner[used]
        table[used, 0] = lo[e]
        table[used, 1] = hi[e]
        table[used, 2] = self.start[e]
        table[used, 3] = self.count[e]
        self._table.append(table)
        return table

    def check(self, tri: np.ndarray, num_vertices: int) -> None:
        """ArgumentError unless this hash was built for ``tri`` and ``num_vertices`` suffice."""
        if self.tri.shape != tri.shape or not np.array_equal(self.tri, tri):
            raise ArgumentError("topology_hash", "topology_hash was built for a different tri "
                                f"(shape {self.tri.shape}); build it with "
                                "antialias_construct_topology_hash(tri) for this one")
        if self.num_vertices > num_vertices:
            raise ArgumentError("topology_hash", f"topology_hash was built for "
                                f"{self.num_vertices} vertices, pos has {num_vertices}")


def _weld(pos, num_vertices: int) -> np.ndarray:
    """canon (V,): the lowest index of the vertices with exactly this vertex's position."""
    p = validate.finite_array("pos", pos, np.float64)
    if p.ndim != 2 or p.shape[1] not in (3, 4) or p.shape[0] < num_vertices:
        raise ArgumentError("pos", "pos for welding must have shape (V, 3) or (V, 4) with V "
                            f">= {num_vertices} (tri's largest index + 1), got {p.shape}")
    _, first, inverse = np.unique(p, axis=0, return_index=True, return_inverse=True)
    return first[inverse.ravel()].astype(np.int64)


def antialias_construct_topology_hash(tri, *, pos=None) -> TopologyHash:
    """The topology hash of ``tri`` (T, 3) for the antialias op (both cores).

    Build it once for a mesh whose triangles do not change. ``pos`` (V, 3) or (V, 4),
    optional: vertices with exactly equal positions are welded, so that a mesh whose
    vertices are duplicated (e.g. at texture seams) has its shared edges recognised instead
    of every edge looking like a silhouette; the positions are read once, here.
    """
    arr = np.asarray(tri)
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ArgumentError("tri", f"tri must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ArgumentError("tri", f"tri must have shape (T, 3), got {arr.shape}")
    if arr.size and arr.min() < 0:
        raise ArgumentError("tri", f"tri must hold vertex indices >= 0, got {int(arr.min())}")
    if arr.size and arr.max() >= 2 ** 31 - 1:
        raise ArgumentError("tri", f"tri holds vertex index {int(arr.max())}, beyond int32")
    tri32 = np.ascontiguousarray(arr, dtype=np.int32)
    num_vertices = int(tri32.max()) + 1 if tri32.size else 0
    if pos is not None:
        canon = _weld(pos, num_vertices)
        num_vertices = len(canon)
    else:
        canon = np.arange(num_vertices, dtype=np.int64)
    t = tri32.astype(np.int64)
    a = canon[t[:, [1, 2, 0]]].ravel()      # edge i joins vertices i+1, i+2; opposite i
    b = canon[t[:, [2, 0, 1]]].ravel()
    slot = np.arange(t.size)                 # 3 t + i
    keys = np.minimum(a, b) * max(num_vertices, 1) + np.maximum(a, b)
    order = np.argsort(keys, kind="stable")
    unique, start, count = np.unique(keys[order], return_index=True, return_counts=True)
    return TopologyHash(tri=tri32, canon=canon, keys=unique.astype(np.int64),
                        start=start.astype(np.int64), count=count.astype(np.int64),
                        entries=slot[order].astype(np.int32), welded=pos is not None)


def topology_hash_for(topology_hash, tri: np.ndarray, num_vertices: int) -> TopologyHash:
    """``topology_hash`` checked against ``tri`` (built from it when None)."""
    if topology_hash is None:
        topology_hash = antialias_construct_topology_hash(tri)
    elif not isinstance(topology_hash, TopologyHash):
        raise ArgumentError("topology_hash", "topology_hash must come from "
                            f"antialias_construct_topology_hash(), got "
                            f"{type(topology_hash).__name__}")
    topology_hash.check(tri, num_vertices)
    return topology_hash


