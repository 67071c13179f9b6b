"""Mesa llvmpipe's coverage rule: fixed-point snapping and edge setup (docs/llvmpipe.md).

Vertices snap to 1/256 px; a pixel center is covered when three integer edge inequalities
hold. This model reproduces llvmpipe's coverage bit for bit for unclipped triangles inside
the viewport; the reference rasterizes with it and GPU-side culling drops what it culls.
"""

from __future__ import annotations

import numpy as np

SUBPIXEL_BITS = 8  # llvmpipe: FIXED_ORDER = 8, so positions snap to 1/256 px
FIXED_ONE = 1 << SUBPIXEL_BITS


def snap(window: np.ndarray, subpixel_bits: int = SUBPIXEL_BITS) -> np.ndarray:
    """Fixed-point vertex positions X = rint((x_w - 0.5) 2^subpixel_bits), as llvmpipe's
    calc_fixed_position (lp_setup_tri.c): the subtraction in float32, the scaling exact,
    the conversion rounding to nearest even. The one snapping of the project: the
    reference's edge setup (:func:`llvmpipe_edges`) and GPU-side culling both use it.

    window: (...) float32 window coordinates (glraster.geometry.window.window_float32).
    Returns float32 of the same shape holding integers exactly (every float32 of magnitude
    2^23 or more is an integer), inf / nan where the input is; the caller converts, after
    masking out what it does not model (the reference keeps |x_w| < 2^22).
    """
    window = np.asarray(window, dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        fixed = window - np.float32(0.5)
        fixed *= np.float32(1 << subpixel_bits)
        return np.rint(fixed, out=fixed)


def llvmpipe_edges(window: np.ndarray):
    """llvmpipe's fixed-point edge setup for triangles given by float32 window positions.

    window: (T, 3, 2) float32. Returns (edges, ok): edges (T, 3, 3) int64 holding
    (dcdx, dcdy, c) per edge and ok (T,) bool (False: zero area after snapping, culled).

    Vertices snap to X = rint((x_w - 0.5) * 256) (round half to even), so pixel (i, j)
    samples the fixed-point point (256 i, 256 j). After ordering the vertices so that the
    opposite vertex lies on the positive side, per edge i -> i+1:
    dcdx = Y_i - Y_{i+1}, dcdy = X_i - X_{i+1}, c = dcdx X_i - dcdy Y_i, plus 1 when dcdx < 0
    or (dcdx == 0 and dcdy > 0). A sample is covered when c - dcdx x + dcdy y >= 1 on all
    three edges: a bottom-left fill rule in GL window coordinates.
    """
    snapped = snap(window).astype(np.int64)
    x, y = snapped[..., 0].copy(), snapped[..., 1].copy()
    side = (y[:, 0] - y[:, 1]) * (x[:, 0] - x[:, 2]) - (x[:, 0] - x[:, 1]) * (y[:, 0] - y[:, 2])
    flip = side < 0
    x[flip, 1], x[flip, 2] = x[flip, 2], x[flip, 1].copy()
    y[flip, 1], y[flip, 2] = y[flip, 2], y[flip, 1].copy()
    nxt = [1, 2, 0]
    dcdx = y - y[:, nxt]
    dcdy = x - x[:, nxt]
    c = dcdx * x - dcdy * y
    c += (dcdx < 0) | ((dcdx == 0) & (dcdy > 0))
    return np.stack([dcdx, dcdy, c], axis=-1), side != 0
