"""Clipping triangles to the GL view volume in clip space (compiled, float64).

The view volume is -w <= x, y, z <= w (GL 4.5 core section 13.7). Sutherland-Hodgman
clipping against those planes gives the polygon the driver's clipper produces; the
reference uses it for bounding boxes of triangles crossing the near or far plane, the
error model for the conditioning of clipped triangles.
"""

from __future__ import annotations

import numpy as np

from glraster import jit

_compiled = jit.njit(nogil=True, error_model="numpy")


@_compiled
def clip_to_planes(vertices, first_axis, poly, scratch):
    """Sutherland-Hodgman clip of a triangle (3, 4) float64 against -w <= c <= w for the
    clip coordinates c from ``first_axis`` to z, in Mesa's order x = +-w, y = +-w, z = +-w
    (first_axis 0: the view volume; 2: the near and far planes). Writes the polygon into
    ``poly`` (at least (9, 4)) using ``scratch`` (the same size); returns its vertex count."""
    poly[:3] = vertices
    n = 3
    for axis in range(first_axis, 3):
        for sign in (1.0, -1.0):          # keep w + c >= 0, then w - c >= 0
            out = 0
            for i in range(n):
                a, b = poly[i], poly[(i + 1) % n]
                da = a[3] + sign * a[axis]
                db = b[3] + sign * b[axis]
                if da >= 0:
                    scratch[out] = a
                    out += 1
                if (da >= 0) != (db >= 0):
                    scratch[out] = a + (b - a) * (da / (da - db))
                    out += 1
            poly[:out] = scratch[:out]
            n = out
            if n == 0:
                return 0
    return n


@_compiled
def near_far_extents(clip, lo, hi):
    """NDC x, y extents of triangles clip (K, 3, 4) float64 after clipping at the near and
    far planes, into lo, hi (K, 2): (inf, -inf) when nothing survives, left as they are
    (the caller's -inf, inf: the whole viewport) when a clipped vertex reaches w ~ 0."""
    poly = np.empty((9, 4))
    scratch = np.empty((9, 4))
    for t in range(clip.shape[0]):
        n = clip_to_planes(clip[t], 2, poly, scratch)
        if n == 0:
            lo[t, :] = np.inf
            hi[t, :] = -np.inf
            continue
        scale = 1.0
        for i in range(n):
            for c in range(3):
                scale = max(scale, abs(poly[i, c]))
        near_eye = False
        for i in range(n):
            near_eye |= not poly[i, 3] > 1e-12 * scale
        if near_eye:
            continue
        for c in range(2):
            lo[t, c], hi[t, c] = np.inf, -np.inf
            for i in range(n):
                ndc = poly[i, c] / poly[i, 3]
                lo[t, c] = min(lo[t, c], ndc)
                hi[t, c] = max(hi[t, c], ndc)
