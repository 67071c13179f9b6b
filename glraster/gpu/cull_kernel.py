"""The tests of :func:`glraster.gpu.cull.cull`, compiled by numba: one pass over the
vertices (outcodes, the driver's float32 window position and its fixed-point snapping),
one over the triangles (the three tests on gathered vertex flags).

The per-vertex values are the float32 and float64 operations of
glraster.geometry.window.window_xy_float32 and glraster.geometry.fill_rule.snap
(round-half-even) in the same order, so every fixed-point vertex is the one the reference
and the driver compute (numba compiles without fast-math: no FMA contraction, no
reordering). tests/gpu/test_cull_kernel.py compares the culling with the NumPy
formulation triangle by triangle.
"""

from __future__ import annotations

import numpy as np

from glraster import jit

_compiled = jit.njit(nogil=True, error_model="numpy")

# what the triangle pass returns per reason, in order
REASONS = ("outside", "zero_area", "backface")


@_compiled
def _window(c, rcp, half):
    """x_w = float32(float64(c * rcp) * h + h), h = float32(W/2): the fused viewport step
    emulated in float64 (glraster.geometry.window._fused_viewport)."""
    h = np.float64(np.float32(half))
    return np.float32(np.float64(c * rcp) * h + h)


@_compiled
def _snap(x_w, one):
    """round-half-even((x_w - 0.5) 2^bits) in float32 (glraster.geometry.fill_rule.snap)."""
    fixed = x_w - np.float32(0.5)
    fixed = fixed * one
    return np.rint(fixed)


@_compiled
def _outcode(pos, v):
    """Vertex v's outcode (GL 4.5 core section 13.7: outside when all three share a
    plane): bits x > w, x < -w, y > w, y < -w, z > w, z < -w."""
    x, y, z, w = pos[v, 0], pos[v, 1], pos[v, 2], pos[v, 3]
    return (np.uint8(x > w) | (np.uint8(x < -w) << 1) | (np.uint8(y > w) << 2)
            | (np.uint8(y < -w) << 3) | (np.uint8(z > w) << 4) | (np.uint8(z < -w) << 5))


@_compiled
def _window_fixed(pos, v, width, height, one, limit):
    """Vertex v's float32 window x, y, its snapped fixed-point X, Y (float64; 0 when not
    bounded), bounded (in front, within depth and |x|, |y| < limit), inside the viewport."""
    x, y, z, w = pos[v, 0], pos[v, 1], pos[v, 2], pos[v, 3]
    rcp = np.float32(1.0) / w
    px = _window(x, rcp, width / 2)
    py = _window(y, rcp, height / 2)
    b = (w > 0) and (abs(z) <= w) and (abs(px) < limit) and (abs(py) < limit)
    fx = np.float64(_snap(px, one)) if b else 0.0
    fy = np.float64(_snap(py, one)) if b else 0.0
    inside = b and px >= 0 and px <= width and py >= 0 and py <= height
    return px, py, fx, fy, b, inside


@_compiled
def sampled_drops(pos, tri, width, height, llvmpipe, subpixel_bits, stride):
    """How many of the triangles 0, stride, 2 stride, ... :func:`cull_flags` (back faces
    kept) drops, their vertices' values computed per corner (no pass over all vertices):
    an estimate of the fraction it drops, for a fraction of its cost."""
    one = np.float32(1 << subpixel_bits)
    limit = np.float32(1 << 22)
    dropped = 0
    for t in range(0, tri.shape[0], stride):
        i0, i1, i2 = tri[t, 0], tri[t, 1], tri[t, 2]
        if (_outcode(pos, i0) & _outcode(pos, i1) & _outcode(pos, i2)) != 0:
            dropped += 1
        elif not llvmpipe:
            if i0 == i1 or i1 == i2 or i2 == i0:
                dropped += 1
        else:
            _, _, fx0, fy0, _, in0 = _window_fixed(pos, i0, width, height, one, limit)
            _, _, fx1, fy1, _, in1 = _window_fixed(pos, i1, width, height, one, limit)
            _, _, fx2, fy2, _, in2 = _window_fixed(pos, i2, width, height, one, limit)
            area = (fx1 - fx0) * (fy2 - fy0) - (fx2 - fx0) * (fy1 - fy0)
            if in0 and in1 and in2 and area == 0:
                dropped += 1
    return dropped


@_compiled
def cull_flags(pos, tri, width, height, backfaces, llvmpipe, subpixel_bits, margin, keep):
    """keep[t] = triangle t may produce a fragment; returns the (outside, zero_area,
    backface) counts. pos (V, 4) float32, tri (T, 3) int, keep (T,) bool (written)."""
    V = pos.shape[0]
    code = np.empty(V, np.uint8)
    window = llvmpipe or backfaces
    n = V if window else 0
    wx = np.empty(n, np.float32)
    wy = np.empty(n, np.float32)
    fx = np.empty(n, np.float64)
    fy = np.empty(n, np.float64)
    bounded = np.empty(n, np.bool_)
    inside = np.empty(n, np.bool_)
    one = np.float32(1 << subpixel_bits)
    limit = np.float32(1 << 22)
    for v in range(V):
        code[v] = _outcode(pos, v)
        if window:
            wx[v], wy[v], fx[v], fy[v], bounded[v], inside[v] = _window_fixed(
                pos, v, width, height, one, limit)
    outside_n = 0
    flat_n = 0
    back_n = 0
    for t in range(tri.shape[0]):
        i0, i1, i2 = tri[t, 0], tri[t, 1], tri[t, 2]
        if (code[i0] & code[i1] & code[i2]) != 0:
            keep[t] = False
            outside_n += 1
            continue
        keep[t] = True
        if not llvmpipe:
            if i0 == i1 or i1 == i2 or i2 == i0:
                keep[t] = False
                flat_n += 1
                continue
        if not window:
            continue
        # snapped coordinates are integers below 2^30: for bounded vertices the doubled
        # area is exact in float64 (|X| < 2^22 inside the viewport, products < 2^46)
        area = ((fx[i1] - fx[i0]) * (fy[i2] - fy[i0])
                - (fx[i2] - fx[i0]) * (fy[i1] - fy[i0]))
        if llvmpipe and inside[i0] and inside[i1] and inside[i2] and area == 0:
            keep[t] = False
            flat_n += 1
            continue
        if backfaces and bounded[i0] and bounded[i1] and bounded[i2] and area < 0:
            x0, x1, x2 = np.float64(wx[i0]), np.float64(wx[i1]), np.float64(wx[i2])
            y0, y1, y2 = np.float64(wy[i0]), np.float64(wy[i1]), np.float64(wy[i2])
            area_f = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if area_f < -margin:
                keep[t] = False
                back_n += 1
    return outside_n, flat_n, back_n
