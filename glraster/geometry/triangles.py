"""Per-triangle geometry in 2D homogeneous window coordinates: what the error model
(:mod:`glraster.verify.tolerance`) needs to know about each triangle of a raster.

The reference rasterizer computes one :class:`TriangleGeometry` per call
(:attr:`glraster.reference.ReferenceRaster.triangles`); the verifier takes it as an explicit
input instead of reaching into the reference's own setup.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster.geometry.conditioning import Conditioning


@dataclass
class TriangleGeometry:
    """Per-triangle data of T triangles, float64 unless noted.

    With homogeneous window coordinates X_i = (x_i + w_i) W/2, Y_i = (y_i + w_i) H/2 of the
    clip-space vertices and M = [[X_0 X_1 X_2], [Y_0 Y_1 Y_2], [w_0 w_1 w_2]], a pixel center
    p has s = M^-1 (p_x, p_y, 1) = adj(M) (p_x, p_y, 1) / det(M), s_i = lambda_i / w_p.

    clip   : (T, 3, 4)  clip-space vertices (x, y, z, w)
    adj    : (T, 3, 3)  adj(M); row i is the edge function
             e_i(p) = adj[i, 0] p_x + adj[i, 1] p_y + adj[i, 2]
    det    : (T,)       det(M); s_i = e_i(p) / det
    depth_plane : (T, 3)  window depth = a p_x + b p_y + c
    planes_crossed : (T,) int  how many of the six clip planes (x, y, z = +-w) some vertex
             is outside of: 0 means the driver draws the triangle unclipped
    x_plane_crossed : (T,) bool  some vertex is outside x = -w or x = +w
    conditioning : :class:`~glraster.geometry.conditioning.Conditioning`, (T,) arrays each:
             how well conditioned each triangle is for float32 interpolation
    """

    clip: np.ndarray
    adj: np.ndarray
    det: np.ndarray
    depth_plane: np.ndarray
    planes_crossed: np.ndarray
    x_plane_crossed: np.ndarray
    conditioning: Conditioning = field(repr=False)
