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
from glraster.gpu import cull_kernel

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


def window_fixed(pos: np.ndarray, resolution, subpixel_bits: int = 8):
    """Per vertex (V,) float32 window x, y and fixed-point X, Y (integers held in float32;
    inf / nan where w = 0) as the driver and the reference compute them: the fused viewport
    transform of glraster.geometry.window and the snapping of glraster.geometry.fill_rule."""
    wx, wy = window_xy_float32(pos, resolution)
    return wx, wy, snap(wx, subpixel_bits), snap(wy, subpixel_bits)


def cull(pos: np.ndarray, tri: np.ndarray, resolution, *, backfaces: bool = False,
         llvmpipe: bool = True, subpixel_bits: int = 8) -> Culling:
    """Which triangles to upload. Work is per vertex where possible (outcodes, window
    positions), then gathered per triangle, in one compiled pass each
    (:func:`glraster.gpu.cull_kernel.cull_flags`).

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
    keep = np.empty(len(tri), bool)
    counts = cull_kernel.cull_flags(np.asarray(pos, np.float32), tri, width, height, backfaces, llvmpipe,
                                    subpixel_bits, BACKFACE_MARGIN_PX2, keep)
    kept = np.flatnonzero(keep).astype(np.int32)
    return Culling(keep, kept, dict(zip(cull_kernel.REASONS, (int(c) for c in counts))))


def dropped_estimate(pos: np.ndarray, tri: np.ndarray, resolution, *, llvmpipe: bool = True,
                     subpixel_bits: int = 8, stride: int = 16) -> float:
    """The fraction of ``tri`` that :func:`cull` (back faces kept) drops, estimated from
    the triangles 0, ``stride``, 2 ``stride``, ... alone (the same tests on them:
    :func:`glraster.gpu.cull_kernel.sampled_drops`); 0.0 for no triangles."""
    if not len(tri):
        return 0.0
    height, width = resolution
    dropped = cull_kernel.sampled_drops(np.asarray(pos, np.float32), tri, width, height,
                                        llvmpipe, subpixel_bits, stride)
    return dropped / len(range(0, len(tri), stride))
