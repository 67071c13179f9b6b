"""Compiled inner loops of the reference rasterizer: fragments, depth test and values.

The reference (:mod:`glraster.reference`) does its per-triangle setup in NumPy; the loops
over pixels run here, compiled by numba. Each loop performs the same IEEE float64
operations in the same order as the formulas documented in reference.py, so the results
do not depend on how the work is split. numba compiles without fast-math, so LLVM neither
contracts ``a * b + c`` into an FMA nor reorders sums; ``error_model="numpy"`` makes a
division by zero give inf/NaN as in NumPy instead of raising.

Depth test state, four arrays over the H*W pixels (row-major, index py * W + px):

    best_depth  (N,) float64   window depth of the winning fragment (inf: none yet)
    best_tri    (N,) int64     its triangle (-1: none)
    best_error  (N,) float64   the bound on the driver's depth error of that fragment
    others_low  (N,) float64   min over the other fragments of depth - its error bound

The winner is the fragment of least depth, and among equal depths the one of the lower
triangle index: GL's LESS test applied in draw order. The state does not depend on the
order in which fragments arrive, and tells where another triangle's depth interval
reaches the winner's, so that the driver may pick either (a depth tie).

``depth_test`` and ``values`` run on every core (numba ``parallel=True``): the depth test
gives each thread a band of rows, the value pass splits the pixels. The others are serial.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from glraster import jit
from glraster.geometry.fill_rule import FIXED_ONE

_compiled = jit.njit(nogil=True, error_model="numpy")
_parallel = jit.njit(nogil=True, error_model="numpy", parallel=True)

# a pixel center with some lambda_k below -this lies outside the float triangle (far above
# the float64 rounding of lambda at pixel coordinates up to 16k)
EXTRAPOLATION_SLACK = 1e-6


@_parallel
def depth_test(span_tri, span_y, span_x0, span_x1, depth_plane, screen_planes, depth_error,
               width, best_depth, best_tri, best_error, others_low, bands, ox=0.5, oy=0.5):
    """Depth-test the fragments of spans: S spans, fragments (x, span_y[s]) of triangle
    span_tri[s] for span_x0[s] <= x <= span_x1[s] (int64 arrays, pixel units).

    depth_plane   (T, 3)     window depth = a p_x + b p_y + c at the pixel center p
    screen_planes (T, 3, 3)  the window-space barycentrics lambda_k as such planes
    depth_error   (T, 2)     bound on the driver's depth error inside the triangle
                             (column 0) and where its planes extrapolate (column 1: a
                             pixel covered outside the float triangle, some lambda_k < 0)
    bands                    the rows are split into this many bands, one per thread, so
                             that no two threads touch the same pixel
    ox, oy                   the sample's position inside the pixel (pixel units; the
                             center 0.5, 0.5): pixel (x, y) is sampled at (x + ox, y + oy)
    """
    height = best_depth.shape[0] // width
    for band in numba.prange(bands):
        first, last = height * band // bands, height * (band + 1) // bands
        for i in range(span_tri.shape[0]):
            py = span_y[i]
            if not first <= py < last:
                continue
            t = span_tri[i]
            a, b, c = depth_plane[t, 0], depth_plane[t, 1], depth_plane[t, 2]
            cy = py + oy
            row = py * width
            # The part of the span inside the float triangle: lambda_k(p) = A p_x + B >=
            # -slack for every k, an interval of p_x (lambda is linear along the row).
            inside_lo, inside_hi = -np.inf, np.inf
            for k in range(3):
                slope = screen_planes[t, k, 0]
                offset = screen_planes[t, k, 1] * cy + screen_planes[t, k, 2] \
                    + EXTRAPOLATION_SLACK
                if slope > 0:
                    inside_lo = max(inside_lo, -offset / slope)
                elif slope < 0:
                    inside_hi = min(inside_hi, -offset / slope)
                elif not offset >= 0:                   # also NaN: never inside
                    inside_hi = -np.inf
            for px in range(span_x0[i], span_x1[i] + 1):
                cx = px + ox
                depth = a * cx + b * cy + c              # (a p_x + b p_y) + c
                # GL stores float32 depth and tests LESS against the cleared 1.0 (NaN fails)
                if not np.float32(depth) < np.float32(1.0):
                    continue
                inside = inside_lo <= cx <= inside_hi
                error = depth_error[t, 0] if inside else depth_error[t, 1]
                p = row + px
                held = best_depth[p]
                if depth < held or (depth == held and t < best_tri[p]):
                    low = held - best_error[p]           # the former winner joins the others
                    best_depth[p] = depth
                    best_tri[p] = t
                    best_error[p] = error
                else:
                    low = depth - error
                if low < others_low[p]:
                    others_low[p] = low


@_compiled
def fixed_point_spans(tris, edges, bbox, one=FIXED_ONE):
    """The covered pixels of triangles with a fixed-point edge setup, as spans.

    tris  (K,) int64        triangles, in draw order
    edges (T, 3, 3) int64   per edge (dcdx, dcdy, c), see fill_rule.fixed_edges
    bbox  (T, 4) int64      inclusive pixel ranges x0, x1, y0, y1 (inside the viewport)
    one   int               fixed-point units per pixel, 2^subpixel_bits (default 256,
                            llvmpipe's)
    Returns (span_tri, span_y, span_x0, span_x1), int64 arrays of the nonempty spans.

    Pixel (x, y) samples the fixed-point point (one x, one y); edge k covers it when
    c - dcdx one x + dcdy one y >= 1. On row y, with K = c + dcdy one y and s = one dcdx,
    that is s x <= K - 1: x <= floor((K - 1) / s) when s > 0, x >= -floor((K - 1) / -s)
    when s < 0, every x or none when s == 0. Exact integer arithmetic, so each row of a
    triangle is one span found in constant time and empty bbox parts cost nothing.
    """
    rows = 0
    for i in range(tris.shape[0]):
        rows += max(bbox[tris[i], 3] - bbox[tris[i], 2] + 1, 0)
    span_tri = np.empty(rows, np.int64)
    span_y = np.empty(rows, np.int64)
    span_x0 = np.empty(rows, np.int64)
    span_x1 = np.empty(rows, np.int64)
    n = 0
    for i in range(tris.shape[0]):
        t = tris[i]
        for py in range(bbox[t, 2], bbox[t, 3] + 1):
            left, right = bbox[t, 0], bbox[t, 1]
            sy = py * one
            for k in range(3):
                slope = edges[t, k, 0] * one
                rhs = edges[t, k, 2] + edges[t, k, 1] * sy - 1
                if slope > 0:
                    right = min(right, rhs // slope)
                elif slope < 0:
                    left = max(left, -(rhs // -slope))
                elif rhs < 0:
                    right = left - 1
            if left <= right:
                span_tri[n], span_y[n], span_x0[n], span_x1[n] = t, py, left, right
                n += 1
    return span_tri[:n], span_y[:n], span_x0[:n], span_x1[:n]


@_compiled
def _grown(array, size):
    """A copy of the 1-D ``array`` with room for ``size`` elements."""
    out = np.empty(size, array.dtype)
    out[: array.shape[0]] = array
    return out


@_compiled
def float_spans(tris, adj, det, depth_plane, bbox, cover, mark_band, band_px, width, band,
                ox=0.5, oy=0.5):
    """Test every pixel center of the bounding boxes of ``tris`` in float64: the covered
    pixels as spans, and the edge band.

    tris (K,) int64; adj (T, 3, 3) edge rows [A, B, C]; det (T,); depth_plane (T, 3);
    bbox (T, 4) int64 as for :func:`fixed_point_spans`. For triangle t:
    - cover[t]: emit its covered pixels, those where every s_k = ((A_k p_x + B_k p_y) +
      C_k) / det >= 0, ((s_0 + s_1) + s_2) > 0 (in front of the eye) and |z_ndc| <= 1;
    - mark_band[t]: set band[p] (N,) bool at the centers p with ((s_0 + s_1) + s_2) > 0
      that lie within ``band_px`` of an edge or of the near/far line and on no edge's
      far side by more than that; s_k |det| / |(A_k, B_k)| is the signed distance to edge k.
    Pixel (x, y) is tested at (x + ox, y + oy): the center by default, a sample position
    when multisampling.
    Returns (span_tri, span_y, span_x0, span_x1) as :func:`fixed_point_spans`.
    """
    # a convex region has one span per row, but rounding may split one: grow as needed
    span_tri = np.empty(256, np.int64)
    span_y = np.empty(256, np.int64)
    span_x0 = np.empty(256, np.int64)
    span_x1 = np.empty(256, np.int64)
    n = 0
    s = np.empty(3)
    dist = np.empty(5)
    grad = np.empty(3)
    for i in range(tris.shape[0]):
        t = tris[i]
        absdet = abs(det[t])
        for k in range(3):
            grad[k] = math.hypot(adj[t, k, 0], adj[t, k, 1])
        zgrad = 2 * math.hypot(depth_plane[t, 0], depth_plane[t, 1])
        for py in range(bbox[t, 2], bbox[t, 3] + 1):
            cy = py + oy
            run = -1                                     # first px of the open span
            for px in range(bbox[t, 0], bbox[t, 1] + 2):
                inside = False
                if px <= bbox[t, 1]:
                    cx = px + ox
                    for k in range(3):
                        s[k] = (adj[t, k, 0] * cx + adj[t, k, 1] * cy + adj[t, k, 2]) / det[t]
                    total = s[0] + s[1] + s[2]
                    z_ndc = 2 * (depth_plane[t, 0] * cx + depth_plane[t, 1] * cy
                                 + depth_plane[t, 2]) - 1
                    inside = (cover[t] and s[0] >= 0 and s[1] >= 0 and s[2] >= 0
                              and total > 0 and abs(z_ndc) <= 1)
                    if mark_band[t] and band_px > 0 and total > 0:
                        for k in range(3):
                            dist[k] = s[k] * absdet / grad[k] if grad[k] > 0 else np.inf
                        dist[3] = (z_ndc + 1) / zgrad if zgrad > 0 else np.inf
                        dist[4] = (1 - z_ndc) / zgrad if zgrad > 0 else np.inf
                        beyond = False
                        near = False
                        for k in range(5):
                            d = -np.inf if math.isnan(dist[k]) else dist[k]
                            beyond |= d < -band_px
                            near |= abs(d) < band_px
                        if near and not beyond:
                            band[py * width + px] = True
                if inside and run < 0:
                    run = px
                elif not inside and run >= 0:
                    if n == span_tri.shape[0]:
                        span_tri = _grown(span_tri, 2 * n)
                        span_y = _grown(span_y, 2 * n)
                        span_x0 = _grown(span_x0, 2 * n)
                        span_x1 = _grown(span_x1, 2 * n)
                    span_tri[n], span_y[n], span_x0[n], span_x1[n] = t, py, run, px - 1
                    n += 1
                    run = -1
    return span_tri[:n], span_y[:n], span_x0[:n], span_x1[:n]


@_parallel
def values(best_tri, width, adj, det, w, z, persp, screen, depth, ox=0.5, oy=0.5):
    """The outputs at every covered pixel from its winning triangle, in float64.

    best_tri (N,) int64; adj (T, 3, 3) edge rows [A, B, C]; det (T,); w, z (T, 3) clip
    w and z per vertex. Fills persp (N, 3), screen (N, 3) and depth (N,) where they are
    not empty (an output that was not requested is passed with length 0):

        s_k    = ((A_k p_x + B_k p_y) + C_k) / det      p = (x + ox, y + oy), by
                                                        default the pixel center
        persp  = s_k / ((s_0 + s_1) + s_2)
        screen = s_k w_k
        depth  = ((s_0 z_0 + s_1 z_1) + s_2 z_2) / 2 + 1/2
    """
    want_persp = persp.shape[0] > 0
    want_screen = screen.shape[0] > 0
    want_depth = depth.shape[0] > 0
    for p in numba.prange(best_tri.shape[0]):         # pixels are independent: all cores
        t = best_tri[p]
        if t < 0:
            continue
        cx = p % width + ox
        cy = p // width + oy
        s0 = (adj[t, 0, 0] * cx + adj[t, 0, 1] * cy + adj[t, 0, 2]) / det[t]
        s1 = (adj[t, 1, 0] * cx + adj[t, 1, 1] * cy + adj[t, 1, 2]) / det[t]
        s2 = (adj[t, 2, 0] * cx + adj[t, 2, 1] * cy + adj[t, 2, 2]) / det[t]
        if want_persp:
            total = s0 + s1 + s2
            persp[p, 0] = s0 / total
            persp[p, 1] = s1 / total
            persp[p, 2] = s2 / total
        if want_screen:
            screen[p, 0] = s0 * w[t, 0]
            screen[p, 1] = s1 * w[t, 1]
            screen[p, 2] = s2 * w[t, 2]
        if want_depth:
            depth[p] = (s0 * z[t, 0] + s1 * z[t, 1] + s2 * z[t, 2]) * 0.5 + 0.5
