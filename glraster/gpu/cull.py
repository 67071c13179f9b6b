"""Deciding, before upload, which triangles cannot produce a fragment.

Every test here is conservative: a triangle is dropped only when the GL pipeline is certain
to drop it too, so the image with and without culling is the same
(``tests/gpu/test_skip.py``, ``tests/gpu/test_cull.py``).

- outside the view volume: all three vertices strictly outside the same clip plane
  (x > w, x < -w, y > w, y < -w, z > w or z < -w; GL 4.5 core section 13.7);
- zero area: on Mesa llvmpipe, a triangle inside the viewport and in front of the eye
  whose vertices snap to zero fixed-point area (llvmpipe culls those itself; see
  glraster.reference.llvmpipe_edges); on other drivers only triangles that repeat a
  vertex index. The window positions and their snapping are the driver's and the
  reference's own (glraster.geometry.window.window_float32, with its fused last step,
  and glraster.geometry.fill_rule.snap), so cull and reference agree on every vertex;
- back faces (only when asked): clockwise in window space (GL's default front face is
  counter-clockwise) by a clear margin in both float and fixed point. The draw also enables
  GL_CULL_FACE, so borderline triangles are left to the driver's own decision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster.geometry.fill_rule import snap
from glraster.geometry.window import window_xy_float32

# A back face is culled on the host only when its doubled window area is below this (px^2)
# in float64 and negative after snapping: far from the driver's rounding.
BACKFACE_MARGIN_PX2 = 1.0 / 64


@dataclass
class Culling:
    """Result of :func:`cull`.

    keep     : (T,) bool     triangle may produce a fragment
    kept     : (K,) int32    indices of the kept triangles into the caller's ``tri``
    reasons  : dict          name -> number of triangles dropped for that reason
    """

    keep: np.ndarray
    kept: np.ndarray
    reasons: dict

    @property
    def all_kept(self) -> bool:
        return len(self.kept) == len(self.keep)


def _area2(x, y, tri):
    """Twice the signed window area (T,) of triangles ``tri`` (T, 3) over per-vertex x, y."""
    x0, x1, x2 = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    y0, y1, y2 = y[tri[:, 0]], y[tri[:, 1]], y[tri[:, 2]]
    return (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)


def window_fixed(pos: np.ndarray, resolution, subpixel_bits: int = 8):
    """Per vertex (V,) float32 window x, y and fixed-point X, Y (integers held in float32;
    inf / nan where w = 0) as the driver and the reference compute them: the fused viewport
    transform of glraster.geometry.window and the snapping of glraster.geometry.fill_rule."""
    wx, wy = window_xy_float32(pos, resolution)
    return wx, wy, snap(wx, subpixel_bits), snap(wy, subpixel_bits)


def cull(pos: np.ndarray, tri: np.ndarray, resolution, *, backfaces: bool = False,
         llvmpipe: bool = True, subpixel_bits: int = 8) -> Culling:
    """Which triangles to upload. Work is per vertex where possible (outcodes, window
    positions), then gathered per triangle.

    Parameters
    ----------
    pos : (V, 4) float32     clip-space positions
    tri : (T, 3) int32       vertex indices
    resolution : (height, width)
    backfaces : bool         also drop clockwise (back-facing) triangles
    llvmpipe : bool          the driver is Mesa llvmpipe, whose zero-area rule is modeled
    subpixel_bits : int      the driver's GL_SUBPIXEL_BITS (llvmpipe: 8)
    """
    height, width = resolution
    x, y, z, w = pos[:, 0], pos[:, 1], pos[:, 2], pos[:, 3]
    # Cohen-Sutherland style outcodes per vertex; a triangle is outside when its three
    # vertices share a bit (GL 4.5 core section 13.7: all outside one clip plane).
    code = (
        (x > w).view(np.uint8) | ((x < -w).view(np.uint8) << 1)
        | ((y > w).view(np.uint8) << 2) | ((y < -w).view(np.uint8) << 3)
        | ((z > w).view(np.uint8) << 4) | ((z < -w).view(np.uint8) << 5)
    )
    i0, i1, i2 = tri[:, 0], tri[:, 1], tri[:, 2]
    outside = (code[i0] & code[i1] & code[i2]) != 0
    keep = ~outside
    reasons = {"outside": int(outside.sum()), "zero_area": 0, "backface": 0}
    if not llvmpipe:
        same = (i0 == i1) | (i1 == i2) | (i2 == i0)
        reasons["zero_area"] = int((same & keep).sum())
        keep &= ~same

    if llvmpipe or backfaces:
        # the driver's window positions and fixed-point vertices, the very transform and
        # snapping of the reference (glraster.geometry.window, fill_rule)
        wx, wy, sx, sy = window_fixed(pos, resolution, subpixel_bits)
        limit = np.float32(1 << 22)
        with np.errstate(invalid="ignore"):
            front_v = (w > 0) & (np.abs(z) <= w)
            bounded_v = front_v & (np.abs(wx) < limit) & (np.abs(wy) < limit)
        # Snapped coordinates are integers below 2^30, held exactly in float64; for
        # triangles inside the viewport (|X| < 2^22) the area products stay below 2^46
        # and are exact, which is where the zero test is used.
        fx = np.where(bounded_v, sx, 0).astype(np.float64)
        fy = np.where(bounded_v, sy, 0).astype(np.float64)
        bounded = bounded_v[i0] & bounded_v[i1] & bounded_v[i2]
        area = _area2(fx, fy, tri)
        if llvmpipe:
            inside_v = bounded_v & (wx >= 0) & (wx <= width) & (wy >= 0) & (wy <= height)
            flat = inside_v[i0] & inside_v[i1] & inside_v[i2] & (area == 0) & keep
            reasons["zero_area"] = int(flat.sum())
            keep &= ~flat
        if backfaces:
            area_f = _area2(wx.astype(np.float64), wy.astype(np.float64), tri)
            back = bounded & (area < 0) & (area_f < -BACKFACE_MARGIN_PX2) & keep
            reasons["backface"] = int(back.sum())
            keep &= ~back
    kept = np.flatnonzero(keep).astype(np.int32)
    return Culling(keep, kept, reasons)
