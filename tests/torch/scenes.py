"""Small scenes for the torch tests, and the check that makes their gradients testable.

Point-sampled rasterization has frozen coverage: its gradient is that of the barycentrics
at fixed pixel centres. A finite difference agrees with it only where no perturbation
moves an edge across a pixel centre, so :func:`edge_margin` measures, in window pixels,
how far the nearest pixel centre is from any edge; the scenes keep it well above the
displacement of gradcheck's steps (eps = 1e-6 in clip units moves a vertex by about
eps * W / (2 w) ~ 1e-5 px here).
"""

from __future__ import annotations

import numpy as np

# Three triangles with perspective (w from 0.7 to 1.6): 0 and 1 share an edge, 2 lies in
# front of both (z/w smaller by > 0.3 everywhere it overlaps them, no depth tie).
POS = np.array([
    [-0.80, -0.68, 0.35, 1.00],
    [1.00, -0.82, 0.52, 1.30],
    [0.13, 0.83, 0.41, 0.70],
    [1.24, 1.23, 0.62, 1.55],
    [-1.17, 0.53, -0.33, 1.45],
    [-0.08, -1.35, -0.21, 1.62],
    [0.22, 0.14, -0.45, 0.93],
])
TRI = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6]], np.int32)
RESOLUTION = (10, 12)

# Vertex colours for interpolate (A = 3).
COLORS = np.array([
    [0.9, 0.1, 0.2], [0.2, 0.8, 0.1], [0.1, 0.3, 0.9], [0.7, 0.7, 0.1],
    [0.5, 0.2, 0.6], [0.3, 0.9, 0.8], [0.8, 0.5, 0.3],
])


def mirrored(pos: np.ndarray) -> np.ndarray:
    """The scene mirrored left to right (x_c -> -x_c): pixel centres map onto pixel centres
    (x + 1/2 -> W - x - 1/2), so the edge margin is the same."""
    out = np.array(pos, np.float64)
    out[..., 0] *= -1
    return out


def window_xy(pos: np.ndarray, resolution) -> np.ndarray:
    """(V, 2) window coordinates of (V, 4) clip positions (all w > 0)."""
    height, width = resolution
    ndc = pos[:, :2] / pos[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) * width / 2, (ndc[:, 1] + 1) * height / 2], -1)


def edge_margin(pos, tri, resolution) -> float:
    """The smallest distance (window pixels) from a pixel centre to a triangle edge."""
    pos = np.asarray(pos, np.float64)
    if (pos[:, 3] <= 0).any():
        raise ValueError("edge_margin needs every w > 0")
    height, width = resolution
    xy = window_xy(pos, resolution)
    gy, gx = np.mgrid[0:height, 0:width]
    p = np.stack([gx.ravel() + 0.5, gy.ravel() + 0.5], -1)          # (P, 2)
    best = np.inf
    for t in np.asarray(tri):
        for i in range(3):
            a, b = xy[t[i]], xy[t[(i + 1) % 3]]
            d = b - a
            s = np.clip(((p - a) @ d) / (d @ d), 0.0, 1.0)
            best = min(best, float(np.linalg.norm(p - (a + s[:, None] * d), axis=1).min()))
    return best
