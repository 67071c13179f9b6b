"""Per-triangle setup of the "homogeneous" and "homogeneous64" methods (shaders/methods/homogeneous.frag).

With homogeneous window coordinates X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2 of the
clip-space vertices, the matrix M = [[X_0 X_1 X_2], [Y_0 Y_1 Y_2], [w_0 w_1 w_2]] maps clip
barycentrics to homogeneous window positions (Olano & Greer 1997). Row i of adj(M),
(A_i, B_i, C_i), is the edge function e_i(p) = A_i p_x + B_i p_y + C_i, and s_i = e_i / det(M).

The setup runs on the host in extended precision (float64 for the float32 shader,
np.longdouble for the float64 one) and hands the shader, per triangle:

- an anchor a: the window position of a vertex in front of the eye (the one nearest the
  viewport), clamped to the viewport and rounded to the 1/256 px grid, so that p - a is
  exact in the shader for every pixel center p;
- k s_i(a) and k grad s_i, each split into high + low parts of the shader's type, with
  k = max_j |w_j| (a scale that keeps the values near 1);
- w_i / k, so that screen_i = (k s_i) (w_i / k).

s_i(a) is evaluated relative to the anchor's vertex j with the adjugate identity
adj(M) M = det(M) I, i.e. e_i(col_j) = delta_ij det:
    w_j e_i(a) = A_i (a_x w_j - X_j) + B_i (a_y w_j - Y_j) + delta_ij det,
so no large cancelling term C_i enters (the error would otherwise grow with |a|).

:func:`setup_numpy` is the formulation in NumPy, for any working precision. The float32
records come from its compiled twin, :func:`glraster.gpu.homogeneous_kernel.records` (the
same float64 operations, bit-identical records, about 10x faster at 30k triangles); the
float64 ones from :func:`setup_numpy` in np.longdouble (which numba does not compile).
"""

from __future__ import annotations

import numpy as np

from glraster.geometry.triangles import edge_functions, homogeneous_vertices
from glraster.gpu import homogeneous_kernel

STRIDE = 24  # values per triangle record, see shaders/methods/homogeneous.frag
ANCHOR_GRID = homogeneous_kernel.ANCHOR_GRID  # anchors on the 1/256 px grid


def setup(clip: np.ndarray, resolution, fp64: bool) -> np.ndarray:
    """Triangle records for homogeneous.frag.

    clip : (T, 3, 4) float32 clip-space vertices. resolution : (height, width).
    Returns a C-contiguous (T, STRIDE) array, float64 if ``fp64`` else float32.
    """
    if fp64:
        return setup_numpy(clip, resolution, np.longdouble, np.float64)
    height, width = resolution
    rec = np.empty((len(clip), STRIDE), np.float32)
    clip = np.ascontiguousarray(clip, np.float32)
    vertices = np.arange(3 * len(clip), dtype=np.int32).reshape(-1, 3)
    homogeneous_kernel.records(clip.reshape(-1, 4), vertices, width, height, rec, False)
    return rec


def setup_numpy(clip: np.ndarray, resolution, work, out_t) -> np.ndarray:
    """:func:`setup` in NumPy, computed in the float type ``work`` (np.float64 for the
    float32 records, np.longdouble for the float64 ones), records of type ``out_t``.

    clip : (T, 3, 4) float32. Returns a C-contiguous (T, STRIDE) ``out_t`` array.
    """
    height, width = resolution
    T = len(clip)
    vertices = homogeneous_vertices(clip, resolution, work)
    X, Y, w = vertices[..., 0], vertices[..., 1], vertices[..., 2]
    adj, _ = edge_functions(vertices)
    A, B, C = adj[..., 0], adj[..., 1], adj[..., 2]
    det = (A * X).sum(1) + (B * Y).sum(1) + (C * w).sum(1)
    det = det / 3  # each vertex's expansion gives det; averaging shares out the rounding

    # anchor: the vertex in front of the eye nearest the viewport, clamped into it
    with np.errstate(divide="ignore", invalid="ignore"):
        vx = np.where(w > 0, X / w, np.nan).astype(np.float64)
        vy = np.where(w > 0, Y / w, np.nan).astype(np.float64)
    ax = np.clip(vx, 0, width)
    ay = np.clip(vy, 0, height)
    moved = np.nan_to_num(np.abs(ax - vx) + np.abs(ay - vy), nan=np.inf)
    m = np.argmin(moved, axis=1)
    rows = np.arange(T)
    has_vertex = np.isfinite(moved[rows, m])
    ax = np.where(has_vertex, ax[rows, m], width / 2)
    ay = np.where(has_vertex, ay[rows, m], height / 2)
    ax = np.rint(ax * ANCHOR_GRID) / ANCHOR_GRID
    ay = np.rint(ay * ANCHOR_GRID) / ANCHOR_GRID

    axw, ayw = ax.astype(work)[:, None], ay.astype(work)[:, None]
    wm, Xm, Ym = w[rows, m][:, None], X[rows, m][:, None], Y[rows, m][:, None]
    delta = (np.arange(3)[None, :] == m[:, None])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e_vertex = (A * (axw * wm - Xm) + B * (ayw * wm - Ym) + delta * det[:, None]) / wm
        e_plain = A * axw + B * ayw + C
        e_a = np.where(has_vertex[:, None], e_vertex, e_plain)
        scale = np.abs(w).max(1) / det
        scale = np.where(np.isfinite(scale), scale, 0)
        gx, gy, sa = A * scale[:, None], B * scale[:, None], e_a * scale[:, None]
        wk = w / np.abs(w).max(1, keepdims=True)

    rec = np.zeros((T, STRIDE), out_t)
    rec[:, 0], rec[:, 1] = ax, ay
    for start, value in ((2, gx), (8, gy), (14, sa)):
        value = np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0)
        with np.errstate(over="ignore"):
            hi = value.astype(out_t)
            lo = (value - hi.astype(work)).astype(out_t)
        rec[:, start:start + 3] = np.nan_to_num(hi, posinf=0.0, neginf=0.0)
        rec[:, start + 3:start + 6] = np.nan_to_num(lo, posinf=0.0, neginf=0.0)
    rec[:, 20:23] = np.nan_to_num(wk)
    return rec
