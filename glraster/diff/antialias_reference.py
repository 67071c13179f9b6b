"""Antialiasing of a rendered image with visibility gradients: the topology hash and the
float64 reference of the forward and backward (NumPy only; docs/differentiable.md,
"Antialias"; seed 003, "Edge Hash Function" and "Antialias").

The model, per pair of neighbouring pixels A, B = A + d (d = (1, 0) or (0, 1)) whose
triangle ids differ:

1. Start in the triangle of the nearer pixel (smaller z/w in ``rast``; an empty pixel is
   never nearer) and walk along the segment towards the other centre.
2. Leave the current triangle through the first edge crossed (s_i = e_i / det, the
   homogeneous inside test, decreasing along the walk). If it is not crossed before the
   other centre, the surface is continuous: no blend (from the first triangle: try the
   other pixel's triangle instead).
3. If another triangle of the mesh shares that edge (the topology hash) and lies beyond it,
   walk on in it; else the edge is the silhouette. It is handled by this pair only when
   the pair's axis is the one most across it (|r_x| >= |r_y| for horizontal pairs,
   |r_y| > |r_x| for vertical ones, r = v_a x v_b the edge's homogeneous line).
4. The crossing tau in (0, 1) (from A's centre) is in the box of A when tau < 1/2 and of B
   when tau > 1/2; that pixel P takes alpha = |1/2 - tau| of its partner's colour:
   out_P = c_P + alpha (c_partner - c_P) — the box-filtered coverage of the part of P's
   box beyond the edge, exact while the edge crosses P's row (column) inside the box.

A pixel blended from several sides sums its weights; with ``convex=True`` (default) weights
summing past 1 are scaled to sum to 1, so the output stays within the inputs' range.

Everything is evaluated in the frame of A's centre: v'_j = ((W/2)(x_j - w_j n_x),
(H/2)(y_j - w_j n_y), w_j), (n_x, n_y) A's centre in NDC, where the edge function at A is the
third component of the row v'_a x v'_b. The GPU (:mod:`glraster.diff.antialias`) does the
same in float32; decisions within a band of their float32 error are counted as ambiguous
(:attr:`Pairs.ambiguous`), never hidden.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster.diff import layout

__all__ = [
    "DECISION_BAND", "MAX_WALK", "Pairs", "ReferenceAntialiasSaved", "TopologyHash",
    "antialias_backward", "antialias_construct_topology_hash", "antialias_forward", "pairs",
]

# A decision (a sign, or a comparison) is ambiguous when the quantity is within this
# multiple of u = 2^-24 of its first-order float32 error bound m (units of u, one rounding
# per operation; see _frame): |q| <= 16 u m. The GPU's quantities err by at most ~u m.
DECISION_BAND = 16 * 2.0 ** -24

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
        """ValueError unless this hash was built for ``tri`` and ``num_vertices`` suffice."""
        if self.tri.shape != tri.shape or not np.array_equal(self.tri, tri):
            raise ValueError("topology_hash was built for a different tri (shape "
                             f"{self.tri.shape}); build it with "
                             "antialias_construct_topology_hash(tri) for this one")
        if self.num_vertices > num_vertices:
            raise ValueError(f"topology_hash was built for {self.num_vertices} vertices, "
                             f"pos has {num_vertices}")


def _weld(pos, num_vertices: int) -> np.ndarray:
    """canon (V,): the lowest index of the vertices with exactly this vertex's position."""
    p = layout.real_array("pos", pos)
    if p.ndim != 2 or p.shape[1] not in (3, 4) or p.shape[0] < num_vertices:
        raise ValueError(f"pos for welding must have shape (V, 3) or (V, 4) with V >= "
                         f"{num_vertices} (tri's largest index + 1), got {p.shape}")
    p = np.ascontiguousarray(p, dtype=np.float64)
    if not np.isfinite(p).all():
        raise ValueError("pos for welding must be finite")
    _, first, inverse = np.unique(p, axis=0, return_index=True, return_inverse=True)
    return first[inverse.ravel()].astype(np.int64)


def antialias_construct_topology_hash(tri, *, pos=None) -> TopologyHash:
    """The topology hash of ``tri`` (T, 3) for :func:`antialias_forward` (and the GPU op).

    Build it once for a mesh whose triangles do not change. ``pos`` (V, 3) or (V, 4),
    optional: vertices with exactly equal positions are welded, so that a mesh whose
    vertices are duplicated (e.g. at texture seams) has its shared edges recognised instead
    of every edge looking like a silhouette; the positions are read once, here.
    """
    arr = np.asarray(tri)
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"tri must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"tri must have shape (T, 3), got {arr.shape}")
    if arr.size and arr.min() < 0:
        raise ValueError(f"tri must hold vertex indices >= 0, got {int(arr.min())}")
    if arr.size and arr.max() >= 2 ** 31 - 1:
        raise ValueError(f"tri holds vertex index {int(arr.max())}, beyond int32")
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
        raise ValueError("topology_hash must come from antialias_construct_topology_hash(), "
                         f"got {type(topology_hash).__name__}")
    topology_hash.check(tri, num_vertices)
    return topology_hash


# --------------------------------------------------------------------------- the pairs


@dataclass
class Pairs:
    """The blended pixel pairs of an image (N of them) and what the backward needs.

    batch (N,), axis (N,) 0 = horizontal, 1 = vertical; a_yx (N, 2) pixel A, B = A + d;
    modified (N, 2) / partner (N, 2) the (y, x) of the pixel that blends and of the one
    whose colour it takes; tau (N,) the crossing from A's centre; alpha (N,) = |1/2 - tau|;
    rows (N, 2) the pos rows (batch offset included) of the edge's vertices a, b;
    tau_mag (N,) the first-order float32 error bound of tau, in units of u.
    ambiguous (B, H, W) bool: pixels of pairs (blended or not) with a decision within
    :data:`DECISION_BAND`; ambiguous_pairs the number of such pairs.
    """

    batch: np.ndarray
    axis: np.ndarray
    a_yx: np.ndarray
    modified: np.ndarray
    partner: np.ndarray
    tau: np.ndarray
    alpha: np.ndarray
    rows: np.ndarray
    tau_mag: np.ndarray
    ambiguous: np.ndarray
    ambiguous_pairs: int = 0
    candidate_pairs: int = 0
    walk_limit: int = 0


def _frame(clip: np.ndarray, ndc: np.ndarray, resolution):
    """Homogeneous window vertices in the frame of a pixel centre, and their error bounds.

    clip (..., 4), ndc (..., 2) the centre in NDC (broadcast); returns v (..., 3) =
    ((W/2)(x - w n_x), (H/2)(y - w n_y), w) and m (..., 3): the first-order bound of a
    float32 evaluation's error in units of u (n computed in float32 (<= 2 u), one rounding
    per operation: m(a b) = m(a)|b| + |a|m(b) + |ab|, m(a - b) = m(a) + m(b) + |a - b|;
    float32 inputs exact, so m(w) = 0)."""
    height, width = resolution
    x, y, w = clip[..., 0], clip[..., 1], clip[..., 3]
    nx, ny = ndc[..., 0], ndc[..., 1]
    dx, dy = x - w * nx, y - w * ny
    v = np.stack([dx * (width / 2), dy * (height / 2), w], -1)
    mx = (2 * np.abs(w) + np.abs(w * nx) + np.abs(dx)) * (width / 2) + np.abs(v[..., 0])
    my = (2 * np.abs(w) + np.abs(w * ny) + np.abs(dy)) * (height / 2) + np.abs(v[..., 1])
    return v, np.stack([mx, my, np.zeros_like(w)], -1)


def _product(a, ma, b, mb):
    return ma * np.abs(b) + np.abs(a) * mb + np.abs(a * b)


def _line(va, vb, ma, mb):
    """r = va x vb (..., 3) and its error bounds (units of u): (r_x, r_y, r_w) with r_w the
    edge function at the frame's centre."""
    r = np.cross(va, vb)
    m = np.stack([
        _product(va[..., 1], ma[..., 1], vb[..., 2], mb[..., 2])
        + _product(va[..., 2], ma[..., 2], vb[..., 1], mb[..., 1]),
        _product(va[..., 2], ma[..., 2], vb[..., 0], mb[..., 0])
        + _product(va[..., 0], ma[..., 0], vb[..., 2], mb[..., 2]),
        _product(va[..., 0], ma[..., 0], vb[..., 1], mb[..., 1])
        + _product(va[..., 1], ma[..., 1], vb[..., 0], mb[..., 0])], -1) + np.abs(r)
    return r, m


def _dot(r, mr, v, mv):
    """r . v over the last axis and its error bound (units of u)."""
    terms = _product(r, mr, v, mv)
    d = (r * v).sum(-1)
    return d, terms.sum(-1) + 2 * np.abs(r * v).sum(-1)


def _near(q, m, band):
    return np.abs(q) <= band * m


MAX_WALK = 8


def pairs(rast, pos, tri, topology_hash: TopologyHash, *, band: float = DECISION_BAND) -> Pairs:
    """Every blended pair of ``rast`` (checked float64 inputs: rast (B, H, W, 4), pos
    (V, 4) or (B, V, 4), tri (T, 3) int32), in float64, with the ambiguous decisions.

    Per pair, a walk along the segment between the centres, starting in the candidate
    pixel's triangle: leave the current triangle through the first edge crossed; if another
    triangle of the mesh shares that edge and lies beyond it, continue in that one, else the
    edge is the silhouette. The walk ends without a blend when it reaches the other centre
    (a continuous surface; in the first triangle: try the other pixel's triangle instead),
    or after :data:`MAX_WALK` triangles (counted in ``walk_limit``)."""
    batch_n, height, width, _ = rast.shape
    ids = layout.rast_ids(rast, len(tri))
    zw = rast[..., 2]
    pos3 = pos if pos.ndim == 3 else pos[None]
    num_vertices = pos3.shape[1]
    stride = num_vertices if pos.ndim == 3 else 0
    tri_flat = tri.ravel().astype(np.int64)
    canon = topology_hash.canon
    entries = topology_hash.entries.astype(np.int64)
    ambiguous = np.zeros((batch_n, height, width), bool)
    out = {k: [] for k in ("batch", "axis", "a_yx", "modified", "partner", "tau", "rows",
                           "tau_mag")}
    n_ambiguous = n_candidates = n_limit = 0
    arange3 = np.arange(3)
    for axis in (0, 1):
        if axis == 0:
            ia, ib = ids[:, :, :-1], ids[:, :, 1:]
        else:
            ia, ib = ids[:, :-1, :], ids[:, 1:, :]
        b, y, x = np.nonzero(ia != ib)
        n = len(b)
        n_candidates += n
        if n == 0:
            continue
        yb, xb = (y, x + 1) if axis == 0 else (y + 1, x)
        t_a, t_b = ids[b, y, x], ids[b, yb, xb]
        z_a, z_b = zw[b, y, x], zw[b, yb, xb]
        first_a = (t_b < 0) | ((t_a >= 0) & ~(z_b < z_a))
        ndc = np.stack([(2 * x + 1) / width - 1, (2 * y + 1) / height - 1], -1)
        pb = b if pos.ndim == 3 else np.zeros_like(b)
        amb = np.zeros(n, bool)
        # walk state: current triangle, direction (+1: from A to B), entry edge slot, step
        own_a = first_a.copy()
        cur = np.where(own_a, t_a, t_b)
        entry = np.full(n, -1)
        step = np.zeros(n, np.int64)
        attempt = np.zeros(n, np.int64)
        active = cur >= 0
        found = np.zeros(n, bool)
        edge_t = np.zeros(n, np.int64)
        edge_i = np.zeros(n, np.int64)
        while active.any():
            k = np.flatnonzero(active)
            vert = tri[cur[k]].astype(np.int64)
            clip = pos3[pb[k][:, None], vert]
            v, m = _frame(clip, ndc[k][:, None, :], (height, width))
            r, rm = _line(v[:, [1, 2, 0]], v[:, [2, 0, 1]], m[:, [1, 2, 0]], m[:, [2, 0, 1]])
            det, det_m = _dot(r[:, 0], rm[:, 0], v[:, 0], m[:, 0])
            amb[k] |= _near(det, det_m, band)
            sgn = np.sign(det)[:, None]
            e_a, e_b = r[..., 2], r[..., 2] + r[..., axis]
            amb[k] |= (_near(e_a, rm[..., 2], band)
                       | _near(e_b, rm[..., 2] + rm[..., axis] + np.abs(e_b), band)).any(-1)
            fwd = own_a[k][:, None]
            own = np.where(fwd, e_a, e_b) * sgn
            other = np.where(fwd, e_b, e_a) * sgn
            leaving = (own > other) & (sgn != 0) & (arange3[None] != entry[k][:, None])
            first = step[k] == 0
            leaving &= ~first[:, None] | (own >= 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                tau = -e_a / r[..., axis]
                tau_m = (rm[..., 2] + np.abs(tau) * rm[..., axis]) / np.abs(r[..., axis]) \
                    + np.abs(tau)
            key = np.where(leaving, np.where(fwd, tau, -tau), np.inf)
            best = np.argmin(key, -1)
            has = leaving.any(-1)
            tb = np.take_along_axis(tau, best[:, None], -1)
            tbm = np.take_along_axis(tau_m, best[:, None], -1)
            rival = leaving & (arange3[None] != best[:, None])
            amb[k] |= (rival & (np.abs(tau - tb) <= band * (tau_m + tbm))).any(-1)
            reached = ~has | (np.take_along_axis(other, best[:, None], -1)[:, 0] >= 0)
            # reached the other centre inside the first triangle: try the other pixel's
            retry = reached & first & (attempt[k] == 0)
            kk = k[retry]
            other_t = np.where(own_a[kk], t_b[kk], t_a[kk])
            own_a[kk] = ~own_a[kk]
            cur[kk] = other_t
            attempt[kk] = 1
            entry[kk] = -1
            active[kk] = other_t >= 0
            active[k[reached & ~retry]] = False
            go = ~reached
            kg, bg = k[go], best[go]
            # the exit edge (a, b) = vertices bg+1, bg+2, opposite bg: who lies beyond it?
            vg = vert[go]
            a_v = vg[np.arange(len(kg)), (bg + 1) % 3]
            b_v = vg[np.arange(len(kg)), (bg + 2) % 3]
            o_v = vg[np.arange(len(kg)), bg]
            rl, rlm = r[go, bg], rm[go, bg]
            vo, mo = v[go, bg], m[go, bg]
            d_f, d_f_m = _dot(rl, rlm, vo, mo)
            amb[kg] |= _near(d_f, d_f_m, band)
            start, count = topology_hash.lookup(a_v, b_v)
            nxt = np.full(len(kg), -1)
            nxt_slot = np.full(len(kg), -1)
            for j in range(int(count.max()) if count.size else 0):
                live = j < count
                ent = entries[np.where(live, start + j, 0)]
                og = tri_flat[ent]
                live &= canon[og] != canon[o_v]
                vgo, mgo = _frame(pos3[pb[kg], og], ndc[kg], (height, width))
                d_g, d_g_m = _dot(rl, rlm, vgo, mgo)
                amb[kg] |= live & _near(d_g, d_g_m, band)
                beyond = live & (np.sign(d_g) * np.sign(d_f) < 0) & (nxt < 0)
                nxt = np.where(beyond, ent // 3, nxt)
                nxt_slot = np.where(beyond, ent % 3, nxt_slot)
            walk_on = nxt >= 0
            sil = kg[~walk_on]
            found[sil] = True
            edge_t[sil] = cur[sil]
            edge_i[sil] = bg[~walk_on]
            active[sil] = False
            kw = kg[walk_on]
            cur[kw] = nxt[walk_on]
            entry[kw] = nxt_slot[walk_on]
            step[kw] += 1
            over = kw[step[kw] >= MAX_WALK]
            n_limit += len(over)
            active[over] = False
        sel = np.flatnonzero(found)
        if sel.size:
            t, i = edge_t[sel], edge_i[sel]
            vert = tri[t].astype(np.int64)
            rows3 = np.arange(len(sel))
            va_i, vb_i = vert[rows3, (i + 1) % 3], vert[rows3, (i + 2) % 3]
            v2, m2 = _frame(pos3[pb[sel][:, None], np.stack([va_i, vb_i], -1)],
                            ndc[sel][:, None, :], (height, width))
            r, rm = _line(v2[:, 0], v2[:, 1], m2[:, 0], m2[:, 1])
            tau = -r[:, 2] / r[:, axis]
            tau_m = (rm[:, 2] + np.abs(tau) * rm[:, axis]) / np.abs(r[:, axis]) + np.abs(tau)
            # orientation: the pair's axis must be the one most across the edge
            d_across, d_along = np.abs(r[:, axis]), np.abs(r[:, 1 - axis])
            keep = d_across >= d_along if axis == 0 else d_across > d_along
            amb[sel] |= _near(d_across - d_along, rm[:, 0] + rm[:, 1], band)
            blend = sel[keep]
            tau, tau_m = tau[keep], tau_m[keep]
            at_a = tau < 0.5
            a_yx = np.stack([y[blend], x[blend]], -1)
            b_yx = np.stack([yb[blend], xb[blend]], -1)
            out["batch"].append(b[blend])
            out["axis"].append(np.full(len(blend), axis))
            out["a_yx"].append(a_yx)
            out["modified"].append(np.where(at_a[:, None], a_yx, b_yx))
            out["partner"].append(np.where(at_a[:, None], b_yx, a_yx))
            out["tau"].append(tau)
            out["tau_mag"].append(tau_m)
            base = b[blend] * stride
            out["rows"].append(np.stack([va_i[keep] + base, vb_i[keep] + base], -1))
        n_ambiguous += int(amb.sum())
        ambiguous[b[amb], y[amb], x[amb]] = True
        ambiguous[b[amb], yb[amb], xb[amb]] = True

    def cat(name, shape, dtype):
        return (np.concatenate(out[name]) if out[name] else np.zeros(shape, dtype))

    tau = cat("tau", (0,), np.float64)
    return Pairs(batch=cat("batch", (0,), np.int64), axis=cat("axis", (0,), np.int64),
                 a_yx=cat("a_yx", (0, 2), np.int64), modified=cat("modified", (0, 2), np.int64),
                 partner=cat("partner", (0, 2), np.int64), tau=tau, alpha=np.abs(0.5 - tau),
                 rows=cat("rows", (0, 2), np.int64), tau_mag=cat("tau_mag", (0,), np.float64),
                 ambiguous=ambiguous, ambiguous_pairs=n_ambiguous,
                 candidate_pairs=n_candidates, walk_limit=n_limit)


# --------------------------------------------------------------------------- forward, backward


@dataclass
class ReferenceAntialiasSaved:
    """What :func:`antialias_backward` needs: the checked float64 inputs and the pairs."""

    color: np.ndarray
    rast: np.ndarray
    pos: np.ndarray
    tri: np.ndarray
    topology_hash: TopologyHash
    pairs: Pairs
    pos_gradient_boost: float
    convex: bool


def check_inputs(color, rast, pos, tri, topology_hash, pos_gradient_boost, convex,
                 dtype=np.float64, ids: bool = False):
    """The checked arguments of antialias (ValueErrors name the argument):
    (color, rast, pos, tri, topology_hash, boost, convex), and with ``ids`` the decoded
    triangle ids (B, H, W) last."""
    rast = layout.image("rast", rast, dtype=dtype)
    batch_n, height, width, _ = rast.shape
    color = layout.image("color", color, dtype=dtype, channels=None)
    if color.shape[:3] != rast.shape[:3] or color.shape[3] < 1:
        raise ValueError(f"color must have shape {(batch_n, height, width)} + (C,) with C >= 1 "
                         f"(rast's B, H, W), got {color.shape}")
    pos = layout.positions(pos, dtype=dtype)
    if pos.ndim == 3 and pos.shape[0] != batch_n:
        raise ValueError(f"pos has a batch of {pos.shape[0]}, rast of {batch_n}: 3-D pos "
                         "needs one entry per image")
    tri = layout.triangles(tri, pos.shape[-2])
    tri_ids = layout.rast_ids(rast, len(tri))
    th = topology_hash_for(topology_hash, tri, pos.shape[-2])
    if isinstance(pos_gradient_boost, (bool, np.bool_)) or not isinstance(
            pos_gradient_boost, (int, float, np.integer, np.floating)) \
            or not np.isfinite(pos_gradient_boost):
        raise ValueError(f"pos_gradient_boost must be a finite number, got {pos_gradient_boost!r}")
    if not isinstance(convex, (bool, np.bool_)):
        raise ValueError(f"convex must be True or False, got {convex!r}")
    out = (color, rast, pos, tri, th, float(pos_gradient_boost), bool(convex))
    return out + (tri_ids,) if ids else out


def _flat(p: Pairs, yx: np.ndarray, height: int, width: int) -> np.ndarray:
    return (p.batch * height + yx[:, 0]) * width + yx[:, 1]


def _weights(p: Pairs, pixels: int, height: int, width: int, convex: bool):
    """(modified flat index, partner flat index, sum of alpha per pixel, scale per pixel)."""
    mod = _flat(p, p.modified, height, width)
    par = _flat(p, p.partner, height, width)
    total = np.bincount(mod, weights=p.alpha, minlength=pixels)
    scale = 1.0 / np.maximum(total, 1.0) if convex else np.ones(pixels)
    return mod, par, total, scale


def antialias_forward(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, *,
                      convex: bool = True):
    """Antialiased ``color`` in float64: returns (out (B, H, W, C), saved)."""
    color, rast, pos, tri, th, boost, convex = check_inputs(
        color, rast, pos, tri, topology_hash, pos_gradient_boost, convex)
    batch_n, height, width, channels = color.shape
    p = pairs(rast, pos, tri, th)
    pixels = batch_n * height * width
    flat = color.reshape(pixels, channels)
    mod, par, _, scale = _weights(p, pixels, height, width, convex)
    w = p.alpha * scale[mod]
    out = flat.copy()
    for c in range(channels):
        out[:, c] += np.bincount(mod, weights=w * (flat[par, c] - flat[mod, c]),
                                 minlength=pixels)
    saved = ReferenceAntialiasSaved(color, rast, pos, tri, th, p, boost, convex)
    return out.reshape(color.shape), saved


def crossing_gradients(pos, rows, a_yx, axis, resolution, dl_dtau, stride_pos=None):
    """dL/d clip of the two edge vertices from dL/dtau per pair: (N, 2, 4) (z column 0).

    tau = -r'_w / r'_d with r' = v'_a x v'_b in the frame of A's centre, so
    dtau/dr' = -C' / r'_d, C' = (tau d, 1) the crossing; dL/dv'_a = v'_b x G,
    dL/dv'_b = G x v'_a (G = dL/dr'); back to clip: dL/dx = (W/2) G_X, dL/dy = (H/2) G_Y,
    dL/dw = G_w - n_x (W/2) G_X - n_y (H/2) G_Y."""
    height, width = resolution
    flatpos = pos.reshape(-1, 4)
    clip = flatpos[rows]                                    # (N, 2, 4)
    nx = (2 * a_yx[:, 1] + 1) / width - 1
    ny = (2 * a_yx[:, 0] + 1) / height - 1
    ndc = np.stack([nx, ny], -1)
    v, _ = _frame(clip, ndc[:, None, :], resolution)
    r = np.cross(v[:, 0], v[:, 1])
    r_d = np.where(axis == 0, r[:, 0], r[:, 1])
    tau = -r[:, 2] / r_d
    c = np.zeros_like(r)
    c[np.arange(len(r)), axis] = tau
    c[:, 2] = 1.0
    g = (dl_dtau * -1.0 / r_d)[:, None] * c
    ga = np.cross(v[:, 1], g)
    gb = np.cross(g, v[:, 0])
    gv = np.stack([ga, gb], 1)                              # (N, 2, 3) d/d(X', Y', w)
    out = np.zeros(clip.shape)
    out[..., 0] = (width / 2) * gv[..., 0]
    out[..., 1] = (height / 2) * gv[..., 1]
    out[..., 3] = gv[..., 2] - nx[:, None] * out[..., 0] - ny[:, None] * out[..., 1]
    return out


def antialias_backward(saved: ReferenceAntialiasSaved, grad_out):
    """(grad_color (B, H, W, C), grad_pos of pos' shape) in float64; the ids and which pairs
    blend stay those of the forward (visibility gradients come through alpha)."""
    color, p = saved.color, saved.pairs
    batch_n, height, width, channels = color.shape
    grad_out = layout.image("grad_out", grad_out, color.shape)
    pixels = batch_n * height * width
    flat = color.reshape(pixels, channels)
    g = grad_out.reshape(pixels, channels)
    mod, par, total, scale = _weights(p, pixels, height, width, saved.convex)
    delta = (g[mod] * (flat[par] - flat[mod])).sum(-1)      # dL/d(raw weight) per pair
    w = p.alpha * scale[mod]
    grad_color = g * (1.0 - np.bincount(mod, weights=w, minlength=pixels))[:, None]
    for c in range(channels):
        grad_color[:, c] += np.bincount(par, weights=w * g[mod, c], minlength=pixels)
    dl_dalpha = scale[mod] * delta
    if saved.convex:
        weighted = np.bincount(mod, weights=p.alpha * delta, minlength=pixels)
        over = total[mod] > 1.0
        dl_dalpha = np.where(over, scale[mod] * (delta - scale[mod] * weighted[mod]), dl_dalpha)
    sign = np.where(p.tau < 0.5, -1.0, 1.0)                 # alpha = 1/2 - tau at A
    grad_pos = np.zeros(saved.pos.reshape(-1, 4).shape)
    if len(p.tau):
        terms = crossing_gradients(saved.pos, p.rows, p.a_yx, p.axis, (height, width),
                                   sign * dl_dalpha)
        for j in range(2):
            for c in (0, 1, 3):
                grad_pos[:, c] += np.bincount(p.rows[:, j], weights=terms[:, j, c],
                                              minlength=len(grad_pos))
    grad_pos *= saved.pos_gradient_boost
    return grad_color.reshape(color.shape), grad_pos.reshape(saved.pos.shape)
