"""Small float64 view and projection matrices for building catalog scenes.

These follow OpenGL conventions (right-handed eye space looking down -z, clip space with
w = -z_eye for perspective); the projection matrices themselves are glraster.geometry.camera's.

All matrices are (4, 4) float64 and act on column vectors: ``clip = P @ V @ [x, y, z, 1]``.
"""

from __future__ import annotations

import numpy as np


def rotation(axis, angle_deg: float) -> np.ndarray:
    """(4, 4) rotation about a 3-vector axis by angle_deg degrees (right-handed)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    a = np.radians(angle_deg)
    x, y, z = axis
    c, s, t = np.cos(a), np.sin(a), 1.0 - np.cos(a)
    m = np.eye(4)
    m[:3, :3] = [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
                 [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
                 [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]
    return m


def to_clip(vertices: np.ndarray, mvp: np.ndarray) -> np.ndarray:
    """Transform (V, 3) world positions by a (4, 4) matrix into (V, 4) float64 clip space."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
    hom = np.concatenate([v, np.ones((len(v), 1))], axis=1)
    return hom @ np.asarray(mvp, dtype=np.float64).T


def window_to_clip(xy_window: np.ndarray, resolution, z_ndc=0.0, w=1.0) -> np.ndarray:
    """Clip-space positions whose window coordinates are xy_window.

    xy_window: (V, 2) window coordinates in pixels (GL convention: pixel (i, j) has its
    center at (i + 0.5, j + 0.5), origin bottom-left). resolution: (height, width).
    z_ndc, w: scalars or (V,) arrays; x, y, z are multiplied by w so the divide by w lands
    on the requested window point. Returns (V, 4) float64.
    """
    xy = np.asarray(xy_window, dtype=np.float64)
    h, w_px = resolution
    n = len(xy)
    z_ndc = np.broadcast_to(np.asarray(z_ndc, dtype=np.float64), (n,))
    w = np.broadcast_to(np.asarray(w, dtype=np.float64), (n,))
    x_ndc = 2.0 * xy[:, 0] / w_px - 1.0
    y_ndc = 2.0 * xy[:, 1] / h - 1.0
    return np.stack([x_ndc * w, y_ndc * w, z_ndc * w, w], axis=1)
