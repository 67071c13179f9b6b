"""Small float64 view and projection matrices for building catalog scenes.

These follow OpenGL conventions (right-handed eye space looking down -z, clip space with
w = -z_eye for perspective); the projection matrices themselves are glraster.geometry.camera's.

All matrices are (4, 4) float64 and act on column vectors: ``clip = P @ V @ [x, y, z, 1]``.
"""

from __future__ import annotations

import numpy as np

from glraster.errors import ArgumentError


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
        raise ArgumentError("vertices", f"vertices must have shape (V, 3), got {v.shape}")
    hom = np.concatenate([v, np.ones((len(v), 1))], axis=1)
    return hom @ np.asarray(mvp, dtype=np.float64).T
