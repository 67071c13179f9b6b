"""The rasterize op's float64 reference core: forward, backward and depth peeling.

The core of :data:`glraster.diff.ops.RASTERIZE` for float64 (the GPU one is
:mod:`glraster.diff.rasterize`, with the same signatures); inputs arrive checked by
:meth:`RASTERIZE.check <glraster.diff.op.Op.check>`. NumPy only (no GL); derivations in
docs/differentiable.md. B, the batch, is always present.

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

Depth peeling (:class:`DepthPeeler`): layer k holds, per pixel, the nearest fragment
strictly behind layer k-1's (window depth, ties to the lower triangle index as GL's LESS in
draw order); layer 0 is :func:`forward`'s raster.
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.diff import layout
from glraster.diff.ids import encode_ids
from glraster.diff.saved import RasterizeSaved
from glraster.geometry.triangles import edge_functions, homogeneous_vertices
from glraster.reference import kernels
from glraster.reference import rasterize as reference_rasterize
from glraster.reference import setup as reference_setup

__all__ = ["DepthPeeler", "RasterizeSaved", "backward", "forward", "rasterize_values",
           "scatter_rows"]


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
    pos = validate.batched_positions(pos)
    tri = validate.triangles(tri, pos.shape[-2])
    space = validate.space(space)
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
    values[:, 3] = encode_ids(px.t)
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


def forward(pos, *, tri, resolution, ranges=None, grad_db: bool = True, space: str = "persp",
            ctx=None):
    """Rasterize in float64 with frozen coverage: ``((rast, rast_db), saved)``.

    pos        : (V, 4) or (B, V, 4) float64 clip-space positions; 3-D is instanced mode
    tri        : (T, 3) int32 vertex indices
    resolution : (H, W)
    ranges     : (B, 2) int64 [first, count] (range mode, 2-D pos), or None
    grad_db    : also return rast_db (else it is (B, H, W, 0))
    space      : "persp" (perspective-correct barycentrics) or "screen" (window space)
    ctx        : ignored (the signature of the GPU core)

    rast    (B, H, W, 4) float64: u = b0, v = b1 (barycentrics of tri[t, 0], tri[t, 1];
            b2 = 1 - u - v), z/w = z_c / w_c of the surface point, id = triangle index + 1
            encoded (:func:`glraster.diff.layout.encode_ids`); in range mode the index is
            into the whole ``tri``. 0 on empty pixels. Rows [y, x], row 0 at the bottom.
    rast_db (B, H, W, 4) float64: (du/dx, du/dy, dv/dx, dv/dy) in window pixels at the
            pixel centre, 0 on empty pixels.
    saved   :class:`RasterizeSaved`
    """
    tri_id = _coverage(pos, tri, resolution, ranges)
    return _layer(pos, tri, resolution, ranges, grad_db, space, tri_id)


def _layer(pos, tri, resolution, ranges, grad_db, space, tri_id):
    """``((rast, rast_db), saved)`` of the raster whose winning triangles are ``tri_id``."""
    rast, db = _assemble(_Pixels(pos, tri, tri_id), space)
    if not grad_db:
        db = np.zeros(rast.shape[:-1] + (0,))
    saved = RasterizeSaved(pos=pos, tri=tri, resolution=tuple(resolution), ranges=ranges,
                           rast=rast, space=space)
    return (rast, db), saved


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


def scatter_rows(index, values, size):
    """(size, C): values (M, C) summed at rows index (M,), in float64 (np.bincount)."""
    out = np.empty((size, values.shape[1]))
    for c in range(values.shape[1]):
        out[:, c] = np.bincount(index, weights=values[:, c], minlength=size)
    return out


def backward(saved: RasterizeSaved, grad_rast=None, grad_db=None, *, needs=None):
    """Gradient of the positions from the gradients of ``rast`` (and ``rast_db``).

    grad_rast : (B, H, W, 4) dL/d rast or None (zero); channels 0 (u) and 1 (v) are used,
                2 (z/w) and 3 (id) ignored: dL/dz = 0, depth gradients go through
                interpolated attributes
    grad_db   : (B, H, W, 4) dL/d rast_db (the second-order terms), or None / (B, H, W, 0)
    needs     : None or (want_pos,)
    Returns ``(grad_pos,)``, float64 with the shape of ``saved.pos``: dL/d(x, y, z, w) of
    every vertex, z always 0; coverage frozen (values on empty pixels contribute nothing);
    None when pos' gradient is not wanted.
    """
    if needs is not None and not needs[0]:
        return (None,)
    if grad_db is not None and grad_db.shape[-1] == 0:
        grad_db = None
    if grad_rast is None and grad_db is None:
        return (np.zeros(saved.pos.shape),)
    px = _Pixels(saved.pos, saved.tri, saved.tri_id)
    g = px.at(grad_rast)[:, :2] if grad_rast is not None else np.zeros((len(px.t), 2))
    h = px.at(grad_db) if grad_db is not None else None
    grad_adj, grad_det, grad_w = _edge_gradients(px, saved.space, g, h)
    grad_clip = _clip_gradients(px, grad_adj, grad_det, grad_w, saved.resolution)
    pos = saved.pos
    num_v = pos.shape[-2]
    index = (px.pos_batch[:, None] * num_v + px.vertex).ravel()
    grad = scatter_rows(index, grad_clip.reshape(-1, 4), pos.size // 4)
    return (grad.reshape(pos.shape),)


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


class _Levels:
    """The fragments of one batch item sorted by (pixel, depth, triangle), each with its
    depth level within its pixel (0 for the nearest depth, ...)."""

    def __init__(self, pos32, tri32, first, resolution):
        pix, t, depth = _fragments(pos32, tri32, resolution)
        order = np.lexsort((t, depth, pix))
        pix, t, depth = pix[order], t[order], depth[order]
        new_pixel = np.r_[True, pix[1:] != pix[:-1]]
        new_level = new_pixel | np.r_[True, depth[1:] != depth[:-1]]
        level = np.cumsum(new_level) - 1
        level -= np.maximum.accumulate(np.where(new_pixel, level, 0))
        # the first fragment of each (pixel, level): the lowest triangle index at that depth
        self.pix, self.t, self.level = pix[new_level], t[new_level] + first, level[new_level]

    def layer(self, k: int, width: int, out: np.ndarray) -> None:
        """Write layer k's triangle ids into ``out`` (H, W) (left -1 where empty)."""
        pick = self.level == k
        out[self.pix[pick] // width, self.pix[pick] % width] = self.t[pick]


class DepthPeeler:
    """Successive float64 depth layers of one scene, from checked rasterize arguments
    (those of :func:`forward`); the same interface as the GPU core's
    :class:`glraster.diff.rasterize.DepthPeeler`.

    Each :meth:`rasterize_next_layer` returns ``((rast, rast_db), saved)`` of the next
    layer, ``saved`` for :func:`backward`. Cost: every fragment of the reference's coverage
    is listed once, at the first layer (memory and time proportional to the summed pixel
    area of the triangles), and sorted by (pixel, depth, triangle); each layer is then one
    pass over that list.
    """

    def __init__(self, pos, *, tri, resolution, ranges=None, grad_db: bool = True,
                 space: str = "persp", ctx=None):
        self.pos, self.tri, self.resolution = pos, tri, tuple(resolution)
        self.ranges, self.grad_db, self.space = ranges, grad_db, space
        self.layer = 0
        self._levels = None

    def rasterize_next_layer(self):
        """The next layer: ``((rast, rast_db), saved)`` as from :func:`forward`."""
        height, width = self.resolution
        if self._levels is None:
            pos32 = self.pos.astype(np.float32)
            self._levels = [(b, _Levels(p, sub, first, self.resolution) if len(sub) else None)
                            for b, first, sub, p in layout.batch_items(pos32, self.tri,
                                                                       self.ranges)]
        ids = np.full((len(self._levels), height, width), -1, np.int64)
        for b, levels in self._levels:
            if levels is not None:
                levels.layer(self.layer, width, ids[b])
        self.layer += 1
        return _layer(self.pos, self.tri, self.resolution, self.ranges, self.grad_db,
                      self.space, ids)

    def release(self):
        self._levels = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
