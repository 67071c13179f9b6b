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


def homogeneous_vertices(clip: np.ndarray, resolution, dtype=np.float64) -> np.ndarray:
    """(T, 3, 3) homogeneous window coordinates (X_j, Y_j, w_j) of vertex j, in ``dtype``:
    X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2, from clip (T, 3, 4); (X/w, Y/w) is the
    window position of GL 4.5 section 13.8 (x_w = (x/w + 1) W/2)."""
    height, width = resolution
    c = np.asarray(clip).astype(dtype)
    w = c[..., 3]
    return np.stack([(c[..., 0] + w) * dtype(width / 2), (c[..., 1] + w) * dtype(height / 2), w],
                    axis=-1)


def edge_functions(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """adj(M) (T, 3, 3) and det(M) (T,) of M = [[X_j], [Y_j], [w_j]] with the columns
    ``vertices`` (T, 3, 3) from :func:`homogeneous_vertices`, in their dtype.

    Row i of adj(M) is vertex i+1 x vertex i+2 (indices mod 3): the edge function
    e_i(p) = A_i p_x + B_i p_y + C_i, zero on the edge opposite vertex i and linear in
    window space (Olano & Greer 1997); its gradient (A_i, B_i) / det is d s_i / d(x, y).
    det(M) = e_0(vertex 0) = (vertex 1 x vertex 2) . vertex 0.
    """
    adj = np.cross(vertices[:, [1, 2, 0]], vertices[:, [2, 0, 1]])
    det = np.einsum("ti,ti->t", adj[:, 0], vertices[:, 0])
    return adj, det
