"""The float64 reference of every differentiable op, forward and backward (seed 003).

Everything here is NumPy in float64; derivations in docs/differentiable.md. Layouts and
argument checks: :mod:`glraster.diff.layout`. B, the batch, is always present.

Rasterize
---------
Coverage and the winning triangle of every pixel come from :func:`glraster.reference.rasterize`
(llvmpipe's fill rule, GL's LESS depth test, on the float32 positions a GPU would see); the
values are then evaluated in float64 from the float64 positions at the pixel centres
p = (x + 0.5, y + 0.5). Per triangle, with the homogeneous window vertices
v_j = (X_j, Y_j, w_j), X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2, and the edge functions
e_i(p) = A_i p_x + B_i p_y + C_i (row i of adj(M) = v_{i+1} x v_{i+2}), S = e_0 + e_1 + e_2:

    persp   b_i = e_i / S                     d b_i/dx = (A_i - b_i sum_j A_j) / S
    screen  b_i = e_i w_i / det               d b_i/dx = A_i w_i / det      (constants)
    z/w     = sum_i e_i z_i / det             the NDC depth of the surface point

(same for y with B). ``rast`` = (b_0, b_1, z/w, id), ``rast_db`` = (d b_0/dx, d b_0/dy,
d b_1/dx, d b_1/dy). Coverage is frozen: point sampling has no visibility gradient, so the
backward is the derivative of these closed forms at the fixed pixel centres, and dL/dz = 0
(channels 2 and 3 of ``grad_rast`` are ignored).

Interpolate
-----------
out = u a[tri_0] + v a[tri_1] + (1 - u - v) a[tri_2] on covered pixels (0 elsewhere), and
d out_k/dx = (a0_k - a2_k) du/dx + (a1_k - a2_k) dv/dx for the chosen ``diff_attrs``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster.diff import layout
from glraster.geometry.triangles import edge_functions, homogeneous_vertices
from glraster.reference import kernels
from glraster.reference import rasterize as reference_rasterize
from glraster.reference import setup as reference_setup

__all__ = [
    "InterpolateSaved",
    "RasterizeSaved",
    "depth_peel",
    "interpolate_backward",
    "interpolate_forward",
    "rasterize_backward",
    "rasterize_forward",
    "rasterize_values",
]


# --------------------------------------------------------------------------- saved state


@dataclass
class RasterizeSaved:
    """What :func:`rasterize_backward` needs from :func:`rasterize_forward`.

    pos        : (V, 4) or (B, V, 4) float64   the positions, as given
    tri        : (T, 3) int32
    resolution : (H, W)
    tri_id     : (B, H, W) int64   the frozen winning triangle (index into tri, -1 empty)
    space      : "persp" | "screen"
    ranges     : (B, 2) int64 or None   range mode's [first, count] rows
    """

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple
    tri_id: np.ndarray
    space: str = "persp"
    ranges: np.ndarray | None = None

    @classmethod
    def from_rast(cls, pos, tri, rast, *, space: str = "persp", ranges=None) -> RasterizeSaved:
        """The saved state of a ``rast`` made elsewhere (a depth-peeling layer, a GPU
        raster): its triangle ids frozen, values re-derived from ``pos``."""
        pos = layout.positions(pos)
        tri = layout.triangles(tri, pos.shape[-2])
        ranges = layout.ranges(ranges, len(tri), pos.ndim)
        rast = layout.image("rast", rast)
        batch = layout.batch_size(pos, ranges)
        if rast.shape[0] != batch:
            raise ValueError(f"rast has a batch of {rast.shape[0]}, pos/ranges of {batch}")
        return cls(pos=pos, tri=tri, resolution=rast.shape[1:3],
                   tri_id=layout.rast_ids(rast, len(tri)), space=layout.space(space),
                   ranges=ranges)


@dataclass
class InterpolateSaved:
    """What :func:`interpolate_backward` needs from :func:`interpolate_forward`.

    attr       : (V, A) or (B', V, A) float64, as given (B' = 1 broadcasts)
    rast       : (B, H, W, 4) float64
    tri        : (T, 3) int32
    tri_id     : (B, H, W) int64   decoded from rast's channel 3 (-1 empty)
    rast_db    : (B, H, W, 4) float64 or None
    diff_attrs : tuple of attribute indices, or None (no out_da)
    """

    attr: np.ndarray
    rast: np.ndarray
    tri: np.ndarray
    tri_id: np.ndarray
    rast_db: np.ndarray | None = None
    diff_attrs: tuple | None = None


# --------------------------------------------------------------------------- rasterize


class _Pixels:
    """The covered pixels of a (B, H, W) id map and their triangles' geometry, float64.

    N covered pixels: batch, py, px, t (N,) int64; pos_batch (N,) the batch of pos they
    read (0 unless instanced); vertex (N, 3) vertex indices; v (N, 3, 3) homogeneous window
    vertices (rows j = (X_j, Y_j, w_j)); adj (N, 3, 3); det (N,); clip (N, 3, 4);
    cx, cy (N,) the evaluation points; e (N, 3) the edge functions there.
    """

    def __init__(self, pos, tri, tri_id, offset=(0.0, 0.0)):
        self.shape = tri_id.shape
        _, height, width = tri_id.shape
        self.batch, self.py, self.px = np.nonzero(tri_id >= 0)
        self.t = tri_id[self.batch, self.py, self.px]
        pos3 = pos if pos.ndim == 3 else pos[None]
        self.pos_batch = self.batch if pos.ndim == 3 else np.zeros_like(self.batch)
        self.vertex = tri[self.t].astype(np.int64)
        self.clip = pos3[self.pos_batch[:, None], self.vertex]
        self.v = homogeneous_vertices(self.clip, (height, width))
        self.adj, self.det = edge_functions(self.v)
        self.cx = self.px + 0.5 + float(offset[0])
        self.cy = self.py + 0.5 + float(offset[1])
        a = self.adj
        self.e = a[..., 0] * self.cx[:, None] + a[..., 1] * self.cy[:, None] + a[..., 2]

    def image(self, values: np.ndarray) -> np.ndarray:
        """(N, C) per-pixel values as a (B, H, W, C) image, 0 on empty pixels."""
        out = np.zeros(self.shape + values.shape[1:])
        out[self.batch, self.py, self.px] = values
        return out

    def at(self, img: np.ndarray) -> np.ndarray:
        """(N, C) values of a (B, H, W, C) image at the covered pixels."""
        return img[self.batch, self.py, self.px]


def _values(px: _Pixels, space: str):
    """(N, 4) rast and (N, 4) rast_db values of the covered pixels (id channel excluded)."""
    e, adj, det = px.e, px.adj, px.det
    a_x, a_y = adj[..., 0], adj[..., 1]
    z = px.clip[..., 2]
    zw = (e * z).sum(-1) / det
    if space == "persp":
        total = e.sum(-1)[:, None]
        b = e / total
        dx = (a_x - b * a_x.sum(-1)[:, None]) / total
        dy = (a_y - b * a_y.sum(-1)[:, None]) / total
    else:
        w = px.clip[..., 3]
        b = e * w / det[:, None]
        dx = a_x * w / det[:, None]
        dy = a_y * w / det[:, None]
    rast = np.stack([b[:, 0], b[:, 1], zw, np.zeros_like(zw)], -1)
    db = np.stack([dx[:, 0], dy[:, 0], dx[:, 1], dy[:, 1]], -1)
    return rast, db


def rasterize_values(pos, tri, tri_id, *, space: str = "persp", offset=(0.0, 0.0)):
    """The rasterize outputs in float64 for given winning triangles (coverage frozen).

    pos    : (V, 4) or (B, V, 4) clip-space positions (float64 math)
    tri    : (T, 3) int
    tri_id : (B, H, W) int, index into tri (-1: empty); in range mode it indexes all of tri
    offset : (dx, dy) pixels added to the pixel centres (the closed forms are evaluated at
             (x + 0.5 + dx, y + 0.5 + dy), for finite differences; ids stay frozen)
    Returns (rast (B, H, W, 4), rast_db (B, H, W, 4)) as :func:`rasterize_forward`.
    """
    pos = layout.positions(pos)
    tri = layout.triangles(tri, pos.shape[-2])
    space = layout.space(space)
    tid = np.asarray(tri_id)
    if tid.ndim != 3 or not np.issubdtype(tid.dtype, np.integer):
        raise ValueError(f"tri_id must be a (B, H, W) integer array, got {tid.dtype} {tid.shape}")
    if pos.ndim == 3 and pos.shape[0] != tid.shape[0]:
        raise ValueError(f"tri_id has a batch of {tid.shape[0]}, pos of {pos.shape[0]}")
    if tid.size and (tid.min() < -1 or tid.max() >= len(tri)):
        raise ValueError(f"tri_id must hold -1 or indices into tri's {len(tri)} triangles, "
                         f"got values in [{tid.min()}, {tid.max()}]")
    px = _Pixels(pos, tri, tid.astype(np.int64), offset)
    return _assemble(px, space)


def _assemble(px: _Pixels, space: str):
    values, db = _values(px, space)
    values[:, 3] = layout.encode_ids(px.t)
    return px.image(values), px.image(db)


def _coverage(pos, tri, resolution, ranges) -> np.ndarray:
    """(B, H, W) int64 winning triangle (index into tri, -1 empty) from the reference."""
    height, width = resolution
    batch = layout.batch_size(pos, ranges)
    out = np.full((batch, height, width), -1, np.int64)
    for b, first, sub, p in layout.batch_items(pos, tri, ranges):
        if len(sub) == 0:
            continue
        r = reference_rasterize(p, sub, resolution, outputs=("tri_id",))
        out[b] = np.where(r.tri_id >= 0, r.tri_id.astype(np.int64) + first, -1)
    return out


def rasterize_forward(pos, tri, resolution, *, ranges=None, space: str = "persp"):
    """Rasterize in float64 with frozen coverage.

    pos        : (V, 4) or (B, V, 4) clip-space positions; 3-D is instanced mode
    tri        : (T, 3) int vertex indices
    resolution : (H, W)
    ranges     : (B, 2) int [first, count] (range mode, 2-D pos), or None
    space      : "persp" (perspective-correct barycentrics) or "screen" (window space)

    Returns (rast, rast_db, saved):

    rast    (B, H, W, 4) float64: u = b0, v = b1 (barycentrics of tri[t, 0], tri[t, 1];
            b2 = 1 - u - v), z/w = z_c / w_c of the surface point, id = triangle index + 1
            encoded (:func:`glraster.diff.layout.encode_ids`); in range mode the index is
            into the whole ``tri``. 0 on empty pixels. Rows [y, x], row 0 at the bottom.
    rast_db (B, H, W, 4) float64: (du/dx, du/dy, dv/dx, dv/dy) in window pixels at the
            pixel centre, 0 on empty pixels.
    saved   :class:`RasterizeSaved`
    """
    pos = layout.positions(pos)
    tri = layout.triangles(tri, pos.shape[-2])
    resolution = layout.resolution(resolution)
    ranges = layout.ranges(ranges, len(tri), pos.ndim)
    space = layout.space(space)
    tri_id = _coverage(pos, tri, resolution, ranges)
    rast, db = _assemble(_Pixels(pos, tri, tri_id), space)
    return rast, db, RasterizeSaved(pos=pos, tri=tri, resolution=resolution, tri_id=tri_id,
                                    space=space, ranges=ranges)


def _three(c0, c1):
    """(N, 3) from the two channels of vertices 0 and 1; vertex 2's is 0."""
    return np.stack([c0, c1, np.zeros_like(c0)], -1)


def _cross(a, b):
    return np.cross(a, b)


def _edge_gradients(px: _Pixels, space: str, g, h):
    """dL/d(edge rows adj) (N, 3, 3), dL/d det (N,) and dL/d w_i held explicitly (N, 3) for
    L = sum_pixels g . (b0, b1) + h . rast_db, g (N, 2), h (N, 4) or None."""
    e, adj, det = px.e, px.adj, px.det
    a_x, a_y = adj[..., 0], adj[..., 1]
    g3 = _three(g[:, 0], g[:, 1])
    grad_ax = np.zeros_like(e)
    grad_ay = np.zeros_like(e)
    grad_det = np.zeros_like(det)
    grad_w = np.zeros_like(e)
    if h is not None:
        hx = _three(h[:, 0], h[:, 2])                 # d/dx of b0, b1
        hy = _three(h[:, 1], h[:, 3])                 # d/dy of b0, b1
    if space == "persp":
        total = e.sum(-1)[:, None]
        b = e / total
        grad_e = (g3 - (g3 * b).sum(-1, keepdims=True)) / total
        if h is not None:
            grad_ax = (hx - (hx * b).sum(-1, keepdims=True)) / total
            grad_ay = (hy - (hy * b).sum(-1, keepdims=True)) / total
            m = hx * a_x.sum(-1, keepdims=True) + hy * a_y.sum(-1, keepdims=True)
            r = (hx * a_x + hy * a_y).sum(-1, keepdims=True)
            q = (b * m).sum(-1, keepdims=True)
            grad_e += (2 * q - r - m) / total**2
    else:
        w = px.clip[..., 3]
        d = det[:, None]
        grad_e = g3 * w / d
        grad_w += g3 * e / d
        grad_det -= (g3 * e * w).sum(-1) / det**2
        if h is not None:
            grad_ax = hx * w / d
            grad_ay = hy * w / d
            grad_w += (hx * a_x + hy * a_y) / d
            grad_det -= (hx * a_x * w + hy * a_y * w).sum(-1) / det**2
    grad_adj = np.stack([grad_ax + grad_e * px.cx[:, None],
                         grad_ay + grad_e * px.cy[:, None], grad_e], -1)
    return grad_adj, grad_det, grad_w


def _clip_gradients(px: _Pixels, grad_adj, grad_det, grad_w, resolution):
    """dL/d clip (N, 3, 4) of each pixel's vertices (z: 0)."""
    height, width = resolution
    v = px.v
    grad_v = grad_det[:, None, None] * px.adj          # d det / d v_j = adj row j
    grad_v[..., 2] += grad_w
    for i in range(3):                                 # row i = v_{i+1} x v_{i+2}
        j, k = (i + 1) % 3, (i + 2) % 3
        grad_v[:, j] += _cross(v[:, k], grad_adj[:, i])
        grad_v[:, k] += _cross(grad_adj[:, i], v[:, j])
    gx = grad_v[..., 0] * (width / 2)
    gy = grad_v[..., 1] * (height / 2)
    return np.stack([gx, gy, np.zeros_like(gx), gx + gy + grad_v[..., 2]], -1)


def _scatter(index, values, size):
    """(size, C): values (M, C) summed at rows index (M,)."""
    out = np.empty((size, values.shape[1]))
    for c in range(values.shape[1]):
        out[:, c] = np.bincount(index, weights=values[:, c], minlength=size)
    return out


def rasterize_backward(saved: RasterizeSaved, grad_rast, grad_db=None) -> np.ndarray:
    """Gradient of the positions from the gradients of ``rast`` (and ``rast_db``).

    grad_rast : (B, H, W, 4)  dL/d rast; channels 0 (u) and 1 (v) are used, 2 (z/w) and 3
                (id) ignored: dL/dz = 0, depth gradients go through interpolated attributes
    grad_db   : (B, H, W, 4) or None   dL/d rast_db (the second-order terms)
    Returns grad_pos, float64 with the shape of ``saved.pos``: dL/d(x, y, z, w) of every
    vertex, z always 0; coverage frozen (values on empty pixels contribute nothing).
    """
    if not isinstance(saved, RasterizeSaved):
        raise ValueError(f"saved must be the RasterizeSaved of rasterize_forward, got "
                         f"{type(saved).__name__}")
    shape = saved.tri_id.shape + (4,)
    grad_rast = layout.image("grad_rast", grad_rast, shape)
    if grad_db is not None:
        grad_db = layout.image("grad_db", grad_db, shape)
    px = _Pixels(saved.pos, saved.tri, saved.tri_id)
    g = px.at(grad_rast)[:, :2]
    h = px.at(grad_db) if grad_db is not None else None
    grad_adj, grad_det, grad_w = _edge_gradients(px, saved.space, g, h)
    grad_clip = _clip_gradients(px, grad_adj, grad_det, grad_w, saved.resolution)
    pos = saved.pos
    num_v = pos.shape[-2]
    index = (px.pos_batch[:, None] * num_v + px.vertex).ravel()
    grad = _scatter(index, grad_clip.reshape(-1, 4), pos.size // 4)
    return grad.reshape(pos.shape)


# --------------------------------------------------------------------------- interpolate


def _attr_pixels(attr, tri, tri_id):
    """(batch, py, px, t, attribute batch, vertex (N, 3), a (N, 3, A)) of covered pixels."""
    batch, py, px = np.nonzero(tri_id >= 0)
    t = tri_id[batch, py, px]
    attr3 = attr if attr.ndim == 3 else attr[None]
    ab = batch if attr3.shape[0] > 1 else np.zeros_like(batch)
    vertex = tri[t].astype(np.int64)
    return batch, py, px, ab, vertex, attr3[ab[:, None], vertex]


def interpolate_forward(attr, rast, tri, rast_db=None, diff_attrs=None):
    """Interpolate vertex attributes with the barycentrics of ``rast`` (float64).

    attr       : (V, A) or (B, V, A) (a batch of 1 broadcasts over rast's B)
    rast       : (B, H, W, 4) from :func:`rasterize_forward`
    tri        : (T, 3) int, the triangles rast's ids index
    rast_db    : (B, H, W, 4) or None; needed with ``diff_attrs``
    diff_attrs : None | "all" | list of attribute indices k

    Returns (out, out_da, saved):

    out    (B, H, W, A): u a[tri_0] + v a[tri_1] + (1 - u - v) a[tri_2], 0 on empty pixels
    out_da (B, H, W, 2 K) or None: (dA_k/dx, dA_k/dy) per chosen attribute in the order
           given, dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx (window pixels)
    saved  :class:`InterpolateSaved`
    """
    rast = layout.image("rast", rast)
    batch = rast.shape[0]
    attr = layout.attributes(attr, batch)
    tri = layout.triangles(tri, attr.shape[-2], "attr")
    tri_id = layout.rast_ids(rast, len(tri))
    chosen = layout.diff_attrs(diff_attrs, attr.shape[-1])
    if rast_db is not None:
        rast_db = layout.image("rast_db", rast_db, rast.shape)
    if chosen is not None and rast_db is None:
        raise ValueError("rast_db is required when diff_attrs is given")
    b, py, px, _, _, a = _attr_pixels(attr, tri, tri_id)
    u, v = rast[b, py, px, 0][:, None], rast[b, py, px, 1][:, None]
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    out = np.zeros(rast.shape[:3] + (attr.shape[-1],))
    out[b, py, px] = u * a0 + v * a1 + (1 - u - v) * a2
    out_da = None
    if chosen is not None:
        k = list(chosen)
        db = rast_db[b, py, px]
        d0, d1 = (a0 - a2)[:, k], (a1 - a2)[:, k]
        dx = d0 * db[:, 0:1] + d1 * db[:, 2:3]
        dy = d0 * db[:, 1:2] + d1 * db[:, 3:4]
        out_da = np.zeros(rast.shape[:3] + (2 * len(k),))
        out_da[b, py, px] = np.stack([dx, dy], -1).reshape(len(b), 2 * len(k))
    saved = InterpolateSaved(attr=attr, rast=rast, tri=tri, tri_id=tri_id,
                             rast_db=rast_db if chosen is not None else None,
                             diff_attrs=chosen)
    return out, out_da, saved


def interpolate_backward(saved: InterpolateSaved, grad_out, grad_out_da=None):
    """Gradients of attr, rast and rast_db from those of out (and out_da).

    grad_out    : (B, H, W, A)
    grad_out_da : (B, H, W, 2 K) or None (only when the forward had diff_attrs)
    Returns (grad_attr, grad_rast, grad_rast_db):
    grad_attr    shape of attr (summed over the batch where attr broadcast)
    grad_rast    (B, H, W, 4): channels u, v; z/w and id 0
    grad_rast_db (B, H, W, 4) (du/dx, du/dy, dv/dx, dv/dy), or None when there is no
                 grad_out_da (or the forward had no diff_attrs)
    """
    if not isinstance(saved, InterpolateSaved):
        raise ValueError(f"saved must be the InterpolateSaved of interpolate_forward, got "
                         f"{type(saved).__name__}")
    rast, attr = saved.rast, saved.attr
    num_a = attr.shape[-1]
    grad_out = layout.image("grad_out", grad_out, rast.shape[:3] + (num_a,))
    if grad_out_da is not None:
        if saved.diff_attrs is None:
            raise ValueError("grad_out_da must be None: the forward had no diff_attrs")
        grad_out_da = layout.image("grad_out_da", grad_out_da,
                                   rast.shape[:3] + (2 * len(saved.diff_attrs),))
    b, py, px, ab, vertex, a = _attr_pixels(attr, saved.tri, saved.tri_id)
    u, v = rast[b, py, px, 0][:, None], rast[b, py, px, 1][:, None]
    go = grad_out[b, py, px]                                   # (N, A)
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    contrib = np.stack([u * go, v * go, (1 - u - v) * go], 1)  # (N, 3, A)
    grad_rast = np.zeros(rast.shape)
    grad_rast[b, py, px, 0] = (go * (a0 - a2)).sum(-1)
    grad_rast[b, py, px, 1] = (go * (a1 - a2)).sum(-1)
    grad_rast_db = None
    if grad_out_da is not None:
        k = list(saved.diff_attrs)
        pick = np.zeros((len(k), num_a))                       # chosen -> attribute (sums repeats)
        pick[np.arange(len(k)), k] = 1.0
        gda = grad_out_da[b, py, px].reshape(len(b), len(k), 2)
        gx, gy = gda[..., 0], gda[..., 1]
        db = saved.rast_db[b, py, px]
        c0 = gx * db[:, 0:1] + gy * db[:, 1:2]                  # dL/d a0_k
        c1 = gx * db[:, 2:3] + gy * db[:, 3:4]                  # dL/d a1_k
        contrib[:, 0] += c0 @ pick
        contrib[:, 1] += c1 @ pick
        contrib[:, 2] -= (c0 + c1) @ pick
        d0, d1 = (a0 - a2)[:, k], (a1 - a2)[:, k]
        grad_rast_db = np.zeros(rast.shape)
        grad_rast_db[b, py, px] = np.stack(
            [(gx * d0).sum(-1), (gy * d0).sum(-1), (gx * d1).sum(-1), (gy * d1).sum(-1)], -1)
    attr_batches = attr.shape[0] if attr.ndim == 3 else 1
    num_v = attr.shape[-2]
    index = (ab[:, None] * num_v + vertex).ravel()
    grad_attr = _scatter(index, contrib.reshape(-1, num_a), attr_batches * num_v)
    return grad_attr.reshape(attr.shape), grad_rast, grad_rast_db


# --------------------------------------------------------------------------- depth peeling


def _fragments(pos32, tri32, resolution):
    """Every fragment of the reference rasterizer (its coverage, before the depth test):
    (pixel (F,) = py W + px, triangle (F,) index into tri32, window depth (F,) float64),
    only those passing GL's test against the cleared depth 1.0."""
    height, width = resolution
    ts = reference_setup(pos32, tri32, resolution, "llvmpipe")
    fixed = np.flatnonzero(ts.fixed_ok)
    loose = np.flatnonzero(~ts.exact | ~ts.fixed_ok)
    band = np.zeros(height * width, bool)
    pix, tris = [], []
    for span_tri, span_y, span_x0, span_x1 in (
        kernels.fixed_point_spans(fixed, ts.fixed, ts.bbox),
        kernels.float_spans(loose, ts.adj, ts.det, ts.depth_plane, ts.bbox, ~ts.fixed_ok,
                            np.zeros(len(tri32), bool), 0.0, width, band),
    ):
        lengths = span_x1 - span_x0 + 1
        if not lengths.sum():
            continue
        start = np.repeat(span_x0 - np.cumsum(lengths) + lengths, lengths)
        x = start + np.arange(lengths.sum())
        pix.append(np.repeat(span_y, lengths) * width + x)
        tris.append(np.repeat(span_tri, lengths))
    if not pix:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    pix, tris = np.concatenate(pix), np.concatenate(tris)
    plane = ts.depth_plane[tris]
    cx, cy = pix % width + 0.5, pix // width + 0.5
    depth = plane[:, 0] * cx + plane[:, 1] * cy + plane[:, 2]
    keep = depth.astype(np.float32) < np.float32(1.0)     # NaN fails too
    return pix[keep], tris[keep], depth[keep]


def depth_peel(pos, tri, resolution, layers, ranges=None, *, space: str = "persp"):
    """Depth peeling in float64: layer k holds, per pixel, the nearest fragment strictly
    behind layer k-1's (window depth, ties to the lower triangle index as GL's LESS in draw
    order); layer 0 is :func:`rasterize_forward`'s raster.

    pos, tri, resolution, ranges, space : as for :func:`rasterize_forward`
    layers : number of layers (>= 1)
    Returns a list of ``layers`` (rast, rast_db) pairs, layouts as rasterize_forward's.
    The backward of a layer is :func:`rasterize_backward` with
    ``RasterizeSaved.from_rast(pos, tri, rast, space=..., ranges=...)``.

    Cost: every fragment of the reference's coverage is listed once (memory and time
    proportional to the summed pixel area of the triangles) and sorted by (pixel, depth,
    triangle); each layer is then one pass over that list.
    """
    pos = layout.positions(pos)
    tri = layout.triangles(tri, pos.shape[-2])
    height, width = layout.resolution(resolution)
    ranges = layout.ranges(ranges, len(tri), pos.ndim)
    space = layout.space(space)
    if isinstance(layers, (bool, np.bool_)) or not isinstance(layers, (int, np.integer)) \
            or layers < 1:
        raise ValueError(f"layers must be an integer >= 1, got {layers!r}")
    batch = layout.batch_size(pos, ranges)
    ids = np.full((int(layers), batch, height, width), -1, np.int64)
    pos32 = layout.positions(pos, np.float32)
    for b, first, sub, p in layout.batch_items(pos32, tri, ranges):
        if len(sub) == 0:
            continue
        pix, t, depth = _fragments(p, sub, (height, width))
        order = np.lexsort((t, depth, pix))
        pix, t, depth = pix[order], t[order], depth[order]
        new_pixel = np.r_[True, pix[1:] != pix[:-1]]
        new_level = new_pixel | np.r_[True, depth[1:] != depth[:-1]]
        # the level of each fragment within its pixel: 0 for the nearest depth, ...
        level = np.cumsum(new_level) - 1
        level -= np.maximum.accumulate(np.where(new_pixel, level, 0))
        for k in range(int(layers)):
            pick = new_level & (level == k)
            ids[k, b, pix[pick] // width, pix[pick] % width] = t[pick] + first
    return [_assemble(_Pixels(pos, tri, ids[k]), space) for k in range(int(layers))]
