"""How well conditioned a triangle is for float32 interpolation: the inputs of the error
model (glraster.verify.tolerance, docs/tolerance.md), from window-space geometry alone.

R (distance from the origin and the viewport center), kappa (cancellation in the area),
D (diameter), S and N (errors carried by vertices the clipper makes), h (smallest altitude)
and wmin (smallest w) per triangle, computed by a compiled loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glraster import jit
from glraster.geometry.clipping import clip_to_planes


@dataclass
class Conditioning:
    """Per-triangle error-model inputs, each (T,) float64 (see triangle_conditioning)."""

    R: np.ndarray
    kappa: np.ndarray
    D: np.ndarray
    S: np.ndarray
    h: np.ndarray
    wmin: np.ndarray
    N: np.ndarray


def triangle_conditioning(clip, simple, resolution) -> Conditioning:
    """Per-triangle (R, kappa, D, S, h, wmin, N), each (T,) float64, from the window-space
    vertices. h is the smallest altitude (px) of a triangle the driver may draw; wmin the
    smallest w of its vertices. N (0 for unclipped triangles) bounds the relative error of the
    window-space blend factor of a clipped vertex: Mesa's clipper takes it from the first
    window coordinate (x, else y) whose clip-space values differ along the clipped edge,
    t = (x_new - x_out) / (x_in - x_out), so it loses eps32 (|x_in| + |x_out|) / |x_in - x_out|
    on nearly vertical edges; that error reaches noperspective values directly.

    S is 0 for unclipped triangles; for clipped ones it is max |clip coordinate| of the
    original vertices over the smallest w of the clipped polygon: a new vertex is a float32
    blend of the originals, so its NDC position and depth carry an error of about eps32 S.

    Triangles that cross a clip plane use the vertices of their polygon clipped to the
    view volume (what the driver's clipper produces; Mesa's clips at the viewport sides
    too once it clips at all); a polygon reaching w <= 0 cannot be measured (inf).
    clip (T, 3, 4) clip-space vertices; simple (T,) bool: the triangle crosses no clip
    plane. Computed by a compiled loop (:func:`_conditioning`).
    """
    height, width = resolution
    T = len(clip)
    cond = Conditioning(*(np.empty(T) for _ in range(7)))
    _conditioning(np.ascontiguousarray(clip, dtype=np.float64), simple,
                  float(width), float(height),
                  cond.R, cond.kappa, cond.D, cond.S, cond.h, cond.wmin, cond.N)
    return cond


@jit.njit(nogil=True, error_model="numpy")
def _conditioning(clip, simple, width, height, R, kappa, D, S, h, wmin, N):
    """Fill the (T,) outputs of :func:`triangle_conditioning` for clip (T, 3, 4) float64;
    simple (T,) bool: the triangle is drawn unclipped."""
    poly = np.empty((9, 4))
    scratch = np.empty((9, 4))
    win = np.empty((9, 2))
    cx, cy = width / 2, height / 2                  # the viewport center, and the scale
    for t in range(clip.shape[0]):
        if simple[t]:
            poly[:3] = clip[t]
            n = 3
        else:
            n = clip_to_planes(clip[t], 0, poly, scratch)
            unmeasurable = n < 3
            for i in range(n):
                unmeasurable |= poly[i, 3] <= 0
            if unmeasurable:
                R[t] = kappa[t] = D[t] = S[t] = N[t] = np.inf
                h[t] = 0.0
                wmin[t] = 1.0
                continue
        lowest_w = np.inf
        for i in range(n):
            win[i, 0] = (poly[i, 0] / poly[i, 3] + 1) * cx
            win[i, 1] = (poly[i, 1] / poly[i, 3] + 1) * cy
            lowest_w = min(lowest_w, poly[i, 3])
        # Window positions come from x_ndc W/2 + W/2 after a float32 divide: their rounding
        # grows with the distance from the viewport center as well as from the origin.
        reach, diameter = 0.0, 0.0
        for i in range(n):
            reach = max(reach, abs(win[i, 0]) + abs(win[i, 1])
                        + abs(win[i, 0] - cx) + abs(win[i, 1] - cy))
            for j in range(n):
                diameter = max(diameter, abs(win[i, 0] - win[j, 0]) + abs(win[i, 1] - win[j, 1]))
        # Every triple of the polygon's vertices: the clipper's triangulation is not known.
        # A triple with zero area (a repeated or collinear clipped vertex) draws nothing.
        worst_kappa, lowest_h = 1.0, np.inf
        for i in range(n):
            for j in range(i + 1, n):
                for k in range(j + 1, n):
                    ax, ay = win[i, 0] - win[j, 0], win[i, 1] - win[j, 1]
                    bx, by = win[i, 0] - win[k, 0], win[i, 1] - win[k, 1]
                    cross = ax * by - ay * bx
                    if cross == 0:
                        continue
                    mag = abs(ax * by) + abs(ay * bx)
                    longest = max(math.hypot(ax, ay), math.hypot(bx, by),
                                  math.hypot(win[j, 0] - win[k, 0], win[j, 1] - win[k, 1]))
                    worst_kappa = max(worst_kappa, mag / abs(cross))
                    lowest_h = min(lowest_h, abs(cross) / longest)
        R[t], kappa[t], D[t], h[t], wmin[t] = reach, worst_kappa, diameter, lowest_h, lowest_w
        if simple[t]:
            S[t] = N[t] = 0.0
            continue
        biggest = 0.0
        for i in range(3):
            for c in range(4):
                biggest = max(biggest, abs(clip[t, i, c]))
        S[t] = biggest / lowest_w
        R[t] = max(reach, S[t] * max(width, height) / 2)
        # Mesa's window-space blend factor: max over the edges of (|a| + |b|) / |a - b| for
        # the NDC coordinate it uses (x when the clip x differ, else y)
        worst = 0.0
        for i in range(3):
            a, b = clip[t, i], clip[t, (i + 1) % 3]
            k = 0 if a[0] != b[0] else 1
            na, nb = a[k] / a[3], b[k] / b[3]
            ratio = (abs(na) + abs(nb)) / abs(na - nb)
            worst = max(worst, np.inf if math.isnan(ratio) else ratio)
        N[t] = worst
