"""The float32 per-triangle setup of :mod:`glraster.gpu.homogeneous`, compiled by numba.

One pass over the triangles, straight from the vertex array and the index array (no
gathered (T, 3, 4) copy, no temporaries), writing the records of
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

import numba
import numpy as np

_compiled = numba.njit(cache=True, nogil=True, error_model="numpy")

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
def records(pos, tri, width, height, out, depth):
    """Write the records of T triangles into ``out``.

    pos   : (V, 4) float32 clip-space vertices
    tri   : (T, 3) integer vertex indices into ``pos``
    width, height : the viewport in pixels
    out   : (T, S) float32, S >= 24 (S >= 28 with ``depth``): every value of the first 24
            (28) columns is written
    depth : also write columns 24..27: z_j / k for j = 0, 1, 2 (k = max_j |w_j|), then 0
    """
    X = np.empty(3)
    Y = np.empty(3)
    W = np.empty(3)
    Z = np.empty(3)
    A = np.empty(3)
    B = np.empty(3)
    C = np.empty(3)
    moved = np.empty(3)
    cx = np.empty(3)
    cy = np.empty(3)
    half_w = width / 2
    half_h = height / 2
    wf = np.float64(width)
    hf = np.float64(height)
    for t in range(tri.shape[0]):
        for j in range(3):
            v = tri[t, j]
            w = np.float64(pos[v, 3])
            X[j] = (np.float64(pos[v, 0]) + w) * half_w
            Y[j] = (np.float64(pos[v, 1]) + w) * half_h
            W[j] = w
            Z[j] = np.float64(pos[v, 2])
        for i in range(3):
            a = (i + 1) % 3
            b = (i + 2) % 3
            A[i] = Y[a] * W[b] - W[a] * Y[b]
            B[i] = W[a] * X[b] - X[a] * W[b]
            C[i] = X[a] * Y[b] - Y[a] * X[b]
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        for i in range(3):
            s1 += A[i] * X[i]
        for i in range(3):
            s2 += B[i] * Y[i]
        for i in range(3):
            s3 += C[i] * W[i]
        det = (s1 + s2 + s3) / 3

        # anchor: the vertex in front of the eye nearest the viewport, clamped into it
        for j in range(3):
            if W[j] > 0:
                vx = X[j] / W[j]
                vy = Y[j] / W[j]
            else:
                vx = np.nan
                vy = np.nan
            cx[j] = _clip(vx, 0.0, wf)
            cy[j] = _clip(vy, 0.0, hf)
            d = abs(cx[j] - vx) + abs(cy[j] - vy)
            if math.isnan(d):
                d = np.inf
            elif d == np.inf:
                d = _DBL_MAX
            moved[j] = d
        m = 0
        for j in range(1, 3):
            if moved[j] < moved[m]:
                m = j
        has_vertex = math.isfinite(moved[m])
        if has_vertex:
            ax, ay = cx[m], cy[m]
        else:
            ax, ay = half_w, half_h
        ax = np.rint(ax * ANCHOR_GRID) / ANCHOR_GRID
        ay = np.rint(ay * ANCHOR_GRID) / ANCHOR_GRID

        k = _max3(abs(W[0]), abs(W[1]), abs(W[2]))
        scale = k / det
        if not math.isfinite(scale):
            scale = 0.0
        out[t, 0] = np.float32(ax)
        out[t, 1] = np.float32(ay)
        wm, xm, ym = W[m], X[m], Y[m]
        for i in range(3):
            if has_vertex:
                delta = 1.0 if i == m else 0.0
                e = (A[i] * (ax * wm - xm) + B[i] * (ay * wm - ym) + delta * det) / wm
            else:
                e = A[i] * ax + B[i] * ay + C[i]
            _split(out, t, 2, i, A[i] * scale)
            _split(out, t, 8, i, B[i] * scale)
            _split(out, t, 14, i, e * scale)
            wk = W[i] / k
            if math.isnan(wk):
                wk = 0.0
            elif math.isinf(wk):
                wk = _DBL_MAX if wk > 0 else -_DBL_MAX
            out[t, 20 + i] = np.float32(wk)
        out[t, 23] = 0.0
        if depth:
            for j in range(3):
                out[t, 24 + j] = np.float32(_finite_or_zero(Z[j] / k))
            out[t, 27] = 0.0
