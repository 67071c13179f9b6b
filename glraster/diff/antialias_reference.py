"""The antialias op's float64 reference core: antialiasing of a rendered image with
visibility gradients, forward and backward, in NumPy (docs/differentiable.md, "Antialias";
Laine et al. 2020, "Modular Primitives for High-Performance Differentiable Rendering").

The core signature of :mod:`glraster.diff.op` (the same as the GPU core,
:mod:`glraster.diff.antialias`): ``forward(color, rast, pos, *, tri, topology_hash,
pos_gradient_boost, convex, ctx) -> ((out,), saved)`` on arrays checked by
:func:`glraster.diff.antialias_args.check`, and ``backward(saved, grad_out, needs=None) ->
(grad_color, None, grad_pos)`` (rast gets no gradient).

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

from dataclasses import dataclass

import numpy as np

from glraster import validate
from glraster.diff.ids import decode_ids
from glraster.diff.antialias_args import AntialiasSaved, wanted
from glraster.diff.topology_hash import TopologyHash, antialias_construct_topology_hash

__all__ = [
    "DECISION_BAND", "MAX_WALK", "Pairs", "TopologyHash", "antialias_construct_topology_hash",
    "backward", "crossing_gradients", "forward", "pairs",
]

# A decision (a sign, or a comparison) is ambiguous when the quantity is within this
# multiple of u = 2^-24 of its first-order float32 error bound m (units of u, one rounding
# per operation; see _frame): |q| <= 16 u m. The GPU's quantities err by at most ~u m.
DECISION_BAND = 16 * 2.0 ** -24


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



@dataclass(frozen=True)
class _Mesh:
    """What every walk reads (checked float64 inputs): pos3 (B or 1, V, 4), tri (T, 3),
    the topology hash's arrays, the resolution (H, W) and the decision band."""

    pos3: np.ndarray
    tri: np.ndarray
    tri_flat: np.ndarray
    canon: np.ndarray
    entries: np.ndarray
    topology_hash: TopologyHash
    resolution: tuple
    band: float


def _exit_edge(mesh: _Mesh, axis, vert, ndc, pb, own_a, entry, first):
    """Where the walk leaves each current triangle (K of them, vertices ``vert`` (K, 3)):
    the first edge crossed along the segment from the own pixel's centre (``own_a``: A's)
    towards the other, never back through the ``entry`` edge. Returns (v, m, r, rm, best,
    reached, ambiguous): the frame's vertices and edge lines with their error bounds, the
    exit edge (K,), whether the other centre comes first (no exit), the ambiguous rows."""
    band = mesh.band
    v, m = _frame(mesh.pos3[pb[:, None], vert], ndc[:, None, :], mesh.resolution)
    r, rm = _line(v[:, [1, 2, 0]], v[:, [2, 0, 1]], m[:, [1, 2, 0]], m[:, [2, 0, 1]])
    det, det_m = _dot(r[:, 0], rm[:, 0], v[:, 0], m[:, 0])
    amb = _near(det, det_m, band)
    sgn = np.sign(det)[:, None]
    # the edge functions at A's centre and at B's (B = A + d: r_w + r_d)
    e_a, e_b = r[..., 2], r[..., 2] + r[..., axis]
    amb |= (_near(e_a, rm[..., 2], band)
            | _near(e_b, rm[..., 2] + rm[..., axis] + np.abs(e_b), band)).any(-1)
    fwd = own_a[:, None]
    own = np.where(fwd, e_a, e_b) * sgn
    other = np.where(fwd, e_b, e_a) * sgn
    arange3 = np.arange(3)[None]
    leaving = (own > other) & (sgn != 0) & (arange3 != entry[:, None])
    leaving &= ~first[:, None] | (own >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = -e_a / r[..., axis]
        tau_m = (rm[..., 2] + np.abs(tau) * rm[..., axis]) / np.abs(r[..., axis]) + np.abs(tau)
    best = np.argmin(np.where(leaving, np.where(fwd, tau, -tau), np.inf), -1)
    tb = np.take_along_axis(tau, best[:, None], -1)
    tbm = np.take_along_axis(tau_m, best[:, None], -1)
    rival = leaving & (arange3 != best[:, None])
    amb |= (rival & (np.abs(tau - tb) <= band * (tau_m + tbm))).any(-1)
    reached = ~leaving.any(-1) | (np.take_along_axis(other, best[:, None], -1)[:, 0] >= 0)
    return v, m, r, rm, best, reached, amb


def _beyond(mesh: _Mesh, vert, exit_, line, line_m, vo, mo, ndc, pb):
    """The mesh's triangle beyond each exit edge (``exit_`` of triangles ``vert`` (K, 3),
    edge line ``line`` (K, 3), the opposite vertex in the frame ``vo`` (K, 3); with error
    bounds ``line_m``, ``mo``): one sharing the edge (the topology hash) whose opposite
    vertex lies on the other side of it. Returns (triangle or -1, its slot of the edge,
    ambiguous rows)."""
    band = mesh.band
    idx = np.arange(len(exit_))
    a_v = vert[idx, (exit_ + 1) % 3]
    b_v = vert[idx, (exit_ + 2) % 3]
    o_v = vert[idx, exit_]
    d_f, d_f_m = _dot(line, line_m, vo, mo)
    amb = _near(d_f, d_f_m, band)
    start, count = mesh.topology_hash.lookup(a_v, b_v)
    nxt = np.full(len(exit_), -1)
    nxt_slot = np.full(len(exit_), -1)
    for j in range(int(count.max()) if count.size else 0):
        live = j < count
        ent = mesh.entries[np.where(live, start + j, 0)]
        og = mesh.tri_flat[ent]
        live &= mesh.canon[og] != mesh.canon[o_v]
        vgo, mgo = _frame(mesh.pos3[pb, og], ndc, mesh.resolution)
        d_g, d_g_m = _dot(line, line_m, vgo, mgo)
        amb |= live & _near(d_g, d_g_m, band)
        beyond = live & (np.sign(d_g) * np.sign(d_f) < 0) & (nxt < 0)
        nxt = np.where(beyond, ent // 3, nxt)
        nxt_slot = np.where(beyond, ent % 3, nxt_slot)
    return nxt, nxt_slot, amb


def _walk(mesh: _Mesh, axis, t_a, t_b, first_a, ndc, pb):
    """Every candidate pair's walk (N pairs): from the nearer pixel's triangle (``first_a``:
    A's) across the mesh to the silhouette. Returns (found (N,) bool, the silhouette edge's
    triangle and slot (N,), ambiguous (N,) bool, walks stopped at MAX_WALK)."""
    n = len(t_a)
    amb = np.zeros(n, bool)
    own_a = first_a.copy()
    cur = np.where(own_a, t_a, t_b)
    entry = np.full(n, -1)
    step = np.zeros(n, np.int64)
    attempt = np.zeros(n, np.int64)
    active = cur >= 0
    found = np.zeros(n, bool)
    edge_t = np.zeros(n, np.int64)
    edge_i = np.zeros(n, np.int64)
    n_limit = 0
    while active.any():
        k = np.flatnonzero(active)
        vert = mesh.tri[cur[k]].astype(np.int64)
        first = step[k] == 0
        v, m, r, rm, best, reached, amb_k = _exit_edge(mesh, axis, vert, ndc[k], pb[k],
                                                       own_a[k], entry[k], first)
        amb[k] |= amb_k
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
        nxt, nxt_slot, amb_g = _beyond(mesh, vert[go], bg, r[go, bg], rm[go, bg], v[go, bg],
                                       m[go, bg], ndc[kg], pb[kg])
        amb[kg] |= amb_g
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
    return found, edge_t, edge_i, amb, n_limit


def _crossings(mesh: _Mesh, axis, sel, edge_t, edge_i, amb, ndc, pb):
    """The pairs ``sel`` whose walk found a silhouette: where its edge crosses the segment
    between the centres (tau from A's, with its error bound in units of u), kept where the
    pair's axis is the one most across the edge. Returns (kept rows of ``sel``, tau, tau's
    bound, the edge's two vertices (K, 2)); marks the orientation test's ambiguous rows."""
    vert = mesh.tri[edge_t[sel]].astype(np.int64)
    i = edge_i[sel]
    rows = np.arange(len(sel))
    ends = np.stack([vert[rows, (i + 1) % 3], vert[rows, (i + 2) % 3]], -1)
    v2, m2 = _frame(mesh.pos3[pb[sel][:, None], ends], ndc[sel][:, None, :], mesh.resolution)
    r, rm = _line(v2[:, 0], v2[:, 1], m2[:, 0], m2[:, 1])
    tau = -r[:, 2] / r[:, axis]
    tau_m = (rm[:, 2] + np.abs(tau) * rm[:, axis]) / np.abs(r[:, axis]) + np.abs(tau)
    # orientation: the pair's axis must be the one most across the edge
    d_across, d_along = np.abs(r[:, axis]), np.abs(r[:, 1 - axis])
    keep = d_across >= d_along if axis == 0 else d_across > d_along
    amb[sel] |= _near(d_across - d_along, rm[:, 0] + rm[:, 1], mesh.band)
    return sel[keep], tau[keep], tau_m[keep], ends[keep]


_PAIR_FIELDS = {"batch": ((0,), np.int64), "axis": ((0,), np.int64),
                "a_yx": ((0, 2), np.int64), "modified": ((0, 2), np.int64),
                "partner": ((0, 2), np.int64), "tau": ((0,), np.float64),
                "rows": ((0, 2), np.int64), "tau_mag": ((0,), np.float64)}


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
    ids = decode_ids(rast[..., 3], "rast channel 3 (triangle id)")
    zw = rast[..., 2]
    pos3 = pos if pos.ndim == 3 else pos[None]
    stride = pos3.shape[1] if pos.ndim == 3 else 0
    mesh = _Mesh(pos3, tri, tri.ravel().astype(np.int64), topology_hash.canon,
                 topology_hash.entries.astype(np.int64), topology_hash, (height, width), band)
    ambiguous = np.zeros((batch_n, height, width), bool)
    out = {k: [] for k in _PAIR_FIELDS}
    n_ambiguous = n_candidates = n_limit = 0
    for axis in (0, 1):
        ia, ib = (ids[:, :, :-1], ids[:, :, 1:]) if axis == 0 else (ids[:, :-1, :], ids[:, 1:, :])
        b, y, x = np.nonzero(ia != ib)
        n_candidates += len(b)
        if len(b) == 0:
            continue
        yb, xb = (y, x + 1) if axis == 0 else (y + 1, x)
        t_a, t_b = ids[b, y, x], ids[b, yb, xb]
        first_a = (t_b < 0) | ((t_a >= 0) & ~(zw[b, yb, xb] < zw[b, y, x]))
        ndc = np.stack([(2 * x + 1) / width - 1, (2 * y + 1) / height - 1], -1)
        pb = b if pos.ndim == 3 else np.zeros_like(b)
        found, edge_t, edge_i, amb, limit = _walk(mesh, axis, t_a, t_b, first_a, ndc, pb)
        n_limit += limit
        sel = np.flatnonzero(found)
        if sel.size:
            blend, tau, tau_m, ends = _crossings(mesh, axis, sel, edge_t, edge_i, amb, ndc, pb)
            at_a = tau < 0.5
            a_yx = np.stack([y[blend], x[blend]], -1)
            b_yx = np.stack([yb[blend], xb[blend]], -1)
            for name, value in (
                    ("batch", b[blend]), ("axis", np.full(len(blend), axis)), ("a_yx", a_yx),
                    ("modified", np.where(at_a[:, None], a_yx, b_yx)),
                    ("partner", np.where(at_a[:, None], b_yx, a_yx)), ("tau", tau),
                    ("tau_mag", tau_m), ("rows", ends + (b[blend] * stride)[:, None])):
                out[name].append(value)
        n_ambiguous += int(amb.sum())
        ambiguous[b[amb], y[amb], x[amb]] = True
        ambiguous[b[amb], yb[amb], xb[amb]] = True
    fields = {name: np.concatenate(out[name]) if out[name] else np.zeros(shape, dtype)
              for name, (shape, dtype) in _PAIR_FIELDS.items()}
    return Pairs(**fields, alpha=np.abs(0.5 - fields["tau"]), ambiguous=ambiguous,
                 ambiguous_pairs=n_ambiguous, candidate_pairs=n_candidates, walk_limit=n_limit)


# --------------------------------------------------------------------------- forward, backward


def _flat(p: Pairs, yx: np.ndarray, height: int, width: int) -> np.ndarray:
    return (p.batch * height + yx[:, 0]) * width + yx[:, 1]


def _weights(p: Pairs, pixels: int, height: int, width: int, convex: bool):
    """(modified flat index, partner flat index, sum of alpha per pixel, scale per pixel)."""
    mod = _flat(p, p.modified, height, width)
    par = _flat(p, p.partner, height, width)
    total = np.bincount(mod, weights=p.alpha, minlength=pixels)
    scale = 1.0 / np.maximum(total, 1.0) if convex else np.ones(pixels)
    return mod, par, total, scale




def forward(color, rast, pos, *, tri, topology_hash, pos_gradient_boost=1.0, convex=True,
            ctx=None):
    """Antialiased ``color`` in float64, on arrays checked by
    :func:`glraster.diff.antialias_args.check` (``ctx`` is ignored).

    Returns ``((out,), saved)``: out (B, H, W, C) float64; saved an
    :class:`~glraster.diff.antialias_args.AntialiasSaved` holding the :class:`Pairs`.
    """
    batch_n, height, width, channels = color.shape
    p = pairs(rast, pos, tri, topology_hash)
    pixels = batch_n * height * width
    flat = color.reshape(pixels, channels)
    mod, par, _, scale = _weights(p, pixels, height, width, convex)
    w = p.alpha * scale[mod]
    out = flat.copy()
    for c in range(channels):
        out[:, c] += np.bincount(mod, weights=w * (flat[par, c] - flat[mod, c]),
                                 minlength=pixels)
    saved = AntialiasSaved(color, rast, pos, tri, topology_hash, float(pos_gradient_boost),
                           bool(convex), pairs=p)
    return (out.reshape(color.shape),), saved


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




def _alpha_gradients(saved: AntialiasSaved, g, flat, mod, par, total, scale):
    """dL/d alpha per pair from g (pixels, C): through the blend and, with ``convex``,
    through the scale of pixels whose weights sum past 1."""
    p = saved.pairs
    pixels = len(flat)
    delta = (g[mod] * (flat[par] - flat[mod])).sum(-1)      # dL/d(raw weight) per pair
    dl_dalpha = scale[mod] * delta
    if saved.convex:
        weighted = np.bincount(mod, weights=p.alpha * delta, minlength=pixels)
        over = total[mod] > 1.0
        dl_dalpha = np.where(over, scale[mod] * (delta - scale[mod] * weighted[mod]), dl_dalpha)
    return dl_dalpha


def backward(saved: AntialiasSaved, grad_out, *, needs=None, deterministic: bool = False,
             accumulate: str | None = None):
    """Gradients of :func:`forward` in float64: ``(grad_color (B, H, W, C), None,
    grad_pos of pos' shape)``, None where ``needs`` (three flags: color, rast, pos) wants
    none (no position gradients are computed then). The ids and which pairs blend stay
    those of the forward (visibility gradients come through alpha). ``deterministic`` and
    ``accumulate`` are the GPU core's options, accepted for the one signature."""
    want_color, want_pos = wanted(needs)
    color, p = saved.color, saved.pairs
    batch_n, height, width, channels = color.shape
    grad_out = (np.zeros(color.shape) if grad_out is None
                else validate.image("grad_out", grad_out, color.shape))
    pixels = batch_n * height * width
    flat = color.reshape(pixels, channels)
    g = grad_out.reshape(pixels, channels)
    mod, par, total, scale = _weights(p, pixels, height, width, saved.convex)
    grad_color = grad_pos = None
    if want_color:
        w = p.alpha * scale[mod]
        grad_color = g * (1.0 - np.bincount(mod, weights=w, minlength=pixels))[:, None]
        for c in range(channels):
            grad_color[:, c] += np.bincount(par, weights=w * g[mod, c], minlength=pixels)
        grad_color = grad_color.reshape(color.shape)
    if want_pos:
        grad_pos = np.zeros(saved.pos.reshape(-1, 4).shape)
        if len(p.tau):
            dl_dalpha = _alpha_gradients(saved, g, flat, mod, par, total, scale)
            sign = np.where(p.tau < 0.5, -1.0, 1.0)         # alpha = 1/2 - tau at A
            terms = crossing_gradients(saved.pos, p.rows, p.a_yx, p.axis, (height, width),
                                       sign * dl_dalpha)
            for j in range(2):
                for c in (0, 1, 3):
                    grad_pos[:, c] += np.bincount(p.rows[:, j], weights=terms[:, j, c],
                                                  minlength=len(grad_pos))
        grad_pos = (grad_pos * saved.pos_gradient_boost).reshape(saved.pos.shape)
    return grad_color, None, grad_pos
