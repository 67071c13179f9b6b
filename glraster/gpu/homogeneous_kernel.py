"""The float32 per-triangle setup of :mod:`glraster.gpu.homogeneous`, compiled by numba.

One pass over the vertices, then one over the triangles, straight from the index array
(no gathered (T, 3, 4) copy), writing the records of
shaders/methods/homogeneous.frag (24 floats) or of shaders/diff/rasterize.frag (the same
24, then z_j / k and one pad: 28 floats).

The kernel performs the float64 operations of the NumPy formulation documented in
:mod:`glraster.gpu.homogeneous` in the same order, so its records are bit-identical to it
(tests/gpu/test_homogeneous_kernel.py compares them bit for bit, signs of zero included):
numba compiles without fast-math, so LLVM neither contracts ``a * b - c`` into an FMA nor
reorders sums; ``error_model="numpy"`` makes a division by zero give inf / NaN as NumPy
does. The NumPy idioms it reproduces:

- ``x.sum(1)`` over 3 values is ``((0.0 + x0) + x1) + x2`` (the +0.0 start turns a sum
  of negative zeros into +0.0);
- ``np.clip`` keeps NaN and -0.0 (``x < lo ? lo : x > hi ? hi : x``);
- ``np.argmin`` takes the first minimum; ``max`` reductions propagate NaN;
- ``np.nan_to_num(x)`` maps NaN to 0 and +-inf to +-DBL_MAX (which float32 rounds to
  +-inf); with ``posinf=0, neginf=0`` every non-finite value becomes 0.

The anchor and the adjugate identity used for s_i(a) are explained in
:mod:`glraster.gpu.homogeneous`; (A_i, B_i, C_i) = vertex i+1 x vertex i+2 as
:func:`glraster.geometry.triangles.edge_functions` (``np.cross``'s component order).
"""

from __future__ import annotations

import math

import numpy as np

from glraster import jit

_compiled = jit.njit(nogil=True, error_model="numpy")

ANCHOR_GRID = 256.0      # 1/256 px, as glraster.gpu.homogeneous.ANCHOR_GRID
_DBL_MAX = np.finfo(np.float64).max


@_compiled
def _finite_or_zero(x):
    return x if math.isfinite(x) else 0.0


@_compiled
def _clip(x, lo, hi):
    """np.clip on one float64: NaN and -0.0 stay as they are."""
    if math.isnan(x):
        return x
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@_compiled
def _max3(a, b, c):
    """np.maximum.reduce over three float64 (NaN propagates)."""
    m = a
    if not (m >= b or math.isnan(m)):
        m = b
    if not (m >= c or math.isnan(m)):
        m = c
    return m


@_compiled
def _split(out, t, start, i, value):
    """value (float64) as float32 hi + lo into out[t, start + i] and out[t, start + 3 + i];
    non-finite parts written as 0."""
    v = _finite_or_zero(value)
    hi = np.float32(v)
    lo = np.float32(v - np.float64(hi))
    out[t, start + i] = _finite_or_zero(hi)
    out[t, start + 3 + i] = _finite_or_zero(lo)


@_compiled
def _window(pos, v, half_w, half_h):
    """Vertex v as float64 (x_w, y_w, w, z): x_w = (x + w) width / 2, y_w likewise (the
    window coordinates times w)."""
    w = np.float64(pos[v, 3])
    return ((np.float64(pos[v, 0]) + w) * half_w, (np.float64(pos[v, 1]) + w) * half_h, w,
            np.float64(pos[v, 2]))


@_compiled
def _clamped(x, y, w, wf, hf):
    """(cx, cy, moved): the vertex's window position clamped into the viewport and the
    L1 distance it moved (inf behind the eye or for NaN; DBL_MAX for an infinite one)."""
    if w > 0:
        vx = x / w
        vy = y / w
    else:
        vx = np.nan
        vy = np.nan
    cx = _clip(vx, 0.0, wf)
    cy = _clip(vy, 0.0, hf)
    d = abs(cx - vx) + abs(cy - vy)
    if math.isnan(d):
        d = np.inf
    elif d == np.inf:
        d = _DBL_MAX
    return cx, cy, d


@_compiled
def _edge(out, t, i, a, b, w, e, scale, k):
    """Columns of edge i: (A, B, e) x scale as hi/lo pairs, w_i / k."""
    _split(out, t, 2, i, a * scale)
    _split(out, t, 8, i, b * scale)
    _split(out, t, 14, i, e * scale)
    wk = w / k
    if math.isnan(wk):
        wk = 0.0
    elif math.isinf(wk):
        wk = _DBL_MAX if wk > 0 else -_DBL_MAX
    out[t, 20 + i] = np.float32(wk)


@_compiled
def _vertices(pos, half_w, half_h, wf, hf):
    """(V, 8) float64 per vertex: x_w, y_w, w, z (:func:`_window`), then cx, cy, moved
    (:func:`_clamped`), one pad: what every triangle of the vertex reads, computed once."""
    vert = np.empty((pos.shape[0], 8))
    for v in range(pos.shape[0]):
        x, y, w, z = _window(pos, v, half_w, half_h)
        cx, cy, moved = _clamped(x, y, w, wf, hf)
        vert[v, 0] = x
        vert[v, 1] = y
        vert[v, 2] = w
        vert[v, 3] = z
        vert[v, 4] = cx
        vert[v, 5] = cy
        vert[v, 6] = moved
        vert[v, 7] = 0.0
    return vert


@_compiled
def records(pos, tri, width, height, out, depth):
    """Write the records of T triangles into ``out``.

    pos   : (V, 4) float32 clip-space vertices
    tri   : (T, 3) integer vertex indices into ``pos``
    width, height : the viewport in pixels
    out   : (T, S) float32, S >= 24 (S >= 28 with ``depth``): every value of the first 24
            (28) columns is written
    depth : also write columns 24..27: z_j / k for j = 0, 1, 2 (k = max_j |w_j|), then 0

    The per-vertex values (window position, the clamped anchor candidate and its two
    divisions) are computed once per vertex (:func:`_vertices`), not once per corner
    (measured 20% faster for the 30,720 triangles of 15,488 vertices of the envmap blob);
    the rest in scalars per triangle, so that the values stay in registers.
    """
    half_w = width / 2
    half_h = height / 2
    wf = np.float64(width)
    hf = np.float64(height)
    vert = _vertices(pos, half_w, half_h, wf, hf)
    for t in range(tri.shape[0]):
        i0, i1, i2 = tri[t, 0], tri[t, 1], tri[t, 2]
        x0, y0, w0, z0 = vert[i0, 0], vert[i0, 1], vert[i0, 2], vert[i0, 3]
        x1, y1, w1, z1 = vert[i1, 0], vert[i1, 1], vert[i1, 2], vert[i1, 3]
        x2, y2, w2, z2 = vert[i2, 0], vert[i2, 1], vert[i2, 2], vert[i2, 3]
        # edge i from vertex i+1 to i+2: (A_i, B_i, C_i) = vertex i+1 x vertex i+2
        a0 = y1 * w2 - w1 * y2
        b0 = w1 * x2 - x1 * w2
        c0 = x1 * y2 - y1 * x2
        a1 = y2 * w0 - w2 * y0
        b1 = w2 * x0 - x2 * w0
        c1 = x2 * y0 - y2 * x0
        a2 = y0 * w1 - w0 * y1
        b2 = w0 * x1 - x0 * w1
        c2 = x0 * y1 - y0 * x1
        s1 = ((0.0 + a0 * x0) + a1 * x1) + a2 * x2
        s2 = ((0.0 + b0 * y0) + b1 * y1) + b2 * y2
        s3 = ((0.0 + c0 * w0) + c1 * w1) + c2 * w2
        det = (s1 + s2 + s3) / 3

        # anchor: the vertex in front of the eye nearest the viewport, clamped into it
        cx, cy, moved = vert[i0, 4], vert[i0, 5], vert[i0, 6]
        m, wm, xm, ym = 0, w0, x0, y0
        cx1, cy1, moved1 = vert[i1, 4], vert[i1, 5], vert[i1, 6]
        if moved1 < moved:
            cx, cy, moved, m, wm, xm, ym = cx1, cy1, moved1, 1, w1, x1, y1
        cx2, cy2, moved2 = vert[i2, 4], vert[i2, 5], vert[i2, 6]
        if moved2 < moved:
            cx, cy, moved, m, wm, xm, ym = cx2, cy2, moved2, 2, w2, x2, y2
        has_vertex = math.isfinite(moved)
        if has_vertex:
            ax, ay = cx, cy
        else:
            ax, ay = half_w, half_h
        ax = np.rint(ax * ANCHOR_GRID) / ANCHOR_GRID
        ay = np.rint(ay * ANCHOR_GRID) / ANCHOR_GRID

        k = _max3(abs(w0), abs(w1), abs(w2))
        scale = k / det
        if not math.isfinite(scale):
            scale = 0.0
        out[t, 0] = np.float32(ax)
        out[t, 1] = np.float32(ay)
        if has_vertex:
            dx = ax * wm - xm
            dy = ay * wm - ym
            e0 = (a0 * dx + b0 * dy + (1.0 if m == 0 else 0.0) * det) / wm
            e1 = (a1 * dx + b1 * dy + (1.0 if m == 1 else 0.0) * det) / wm
            e2 = (a2 * dx + b2 * dy + (1.0 if m == 2 else 0.0) * det) / wm
        else:
            e0 = a0 * ax + b0 * ay + c0
            e1 = a1 * ax + b1 * ay + c1
            e2 = a2 * ax + b2 * ay + c2
        _edge(out, t, 0, a0, b0, w0, e0, scale, k)
        _edge(out, t, 1, a1, b1, w1, e1, scale, k)
        _edge(out, t, 2, a2, b2, w2, e2, scale, k)
        out[t, 23] = 0.0
        if depth:
            out[t, 24] = np.float32(_finite_or_zero(z0 / k))
            out[t, 25] = np.float32(_finite_or_zero(z1 / k))
            out[t, 26] = np.float32(_finite_or_zero(z2 / k))
            out[t, 27] = 0.0
