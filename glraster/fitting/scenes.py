"""The fits' scenes and random draws, NumPy only.

Quaternions are (w, x, y, z), unit length after normalizing; rotation matrices act on
column vectors (``p' = R p``). Views are model-view-projection matrices (4, 4) that put an
object at the origin ``distance`` in front of a perspective camera looking down -z.

The cube (glraster's own, after the idea of nvdiffrast's cube sample): the unit cube
(vertices at +-0.5, 12 triangles, :func:`glraster.geometry.shapes.box`) with one colour
per vertex, 0.15 + 0.7 (x + 0.5, y + 0.5, z + 0.5), an RGB cube kept off the black
background, seen from ``DISTANCE`` with a vertical field of view of ``FOVY`` degrees.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager

import numpy as np

from glraster.geometry import camera, shapes

__all__ = ["DISPLAY_QUATERNIONS", "DISTANCE", "FOVY", "Timer", "angle_degrees", "cube",
           "cube_symmetries", "first_below", "pose_camera", "procedural_texture",
           "psnr", "quaternion_matrices", "random_quaternions", "uv_sphere", "view_matrices"]

DISTANCE = 3.0
FOVY = 40.0
# Two fixed views for the before/after pictures: three faces of the cube each.
DISPLAY_QUATERNIONS = np.array([[0.88, 0.28, 0.36, 0.10], [0.35, -0.20, 0.85, 0.35]])


def cube():
    """(vertices (8, 3) float64, triangles (12, 3) int64, colours (8, 3) float64)."""
    vertices, triangles = shapes.box()
    return vertices, triangles, 0.15 + 0.7 * (vertices + 0.5)


def random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) float64 unit quaternions, uniform over the rotations (normalized 4-D
    Gaussians), with w >= 0."""
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q


def quaternion_matrices(q) -> np.ndarray:
    """(..., 3, 3) float64 rotation matrices of (..., 4) quaternions (normalized first)."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = (q[..., k] for k in range(4))
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]
    return np.stack(rows, -1).reshape(q.shape[:-1] + (3, 3))


def angle_degrees(q1, q2) -> np.ndarray:
    """The rotation angle between two rotations given as quaternions, degrees in [0, 180]
    (q and -q are the same rotation): 4 atan2(|a - b|, |a + b|) of the unit quaternions
    with b's sign matched to a, which stays accurate for small angles (2 arccos |a . b|
    loses half the digits there)."""
    a = np.asarray(q1, np.float64)
    b = np.asarray(q2, np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    a, b = np.broadcast_arrays(a, b)
    b = b * np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return np.degrees(4.0 * np.arctan2(np.linalg.norm(a - b, axis=-1),
                                       np.linalg.norm(a + b, axis=-1)))


def cube_symmetries() -> np.ndarray:
    """(24, 4) unit quaternions of the rotations that map the cube onto itself (w >= 0):
    the identity and the half turns about the axes; the 8 (1, +-1, +-1, +-1)/2 (thirds of a
    turn about the body diagonals); the 12 with two entries +-1/sqrt(2) (quarter turns
    about the axes, half turns about the face diagonals)."""
    out = [np.eye(4)[k] for k in range(4)]
    for signs in np.ndindex(2, 2, 2):
        out.append(np.array([1.0] + [1.0 - 2.0 * b for b in signs]) / 2.0)
    for i in range(4):
        for j in range(i + 1, 4):
            for sign in (1.0, -1.0):
                q = np.zeros(4)
                q[i], q[j] = 1.0, sign
                out.append(q / np.sqrt(2.0))
    return np.array(out)


def view_matrices(rotations, *, distance: float, fovy: float, near: float = 0.5,
                  far: float = 20.0, offsets=None) -> np.ndarray:
    """(N, 4, 4) float64 ``proj @ translate(0, 0, -distance) @ rotate``: an object at the
    origin turned by each of the (N, 3, 3) ``rotations``, seen by a square perspective
    camera of vertical field of view ``fovy`` degrees. ``distance`` may be a scalar or (N,);
    ``offsets`` (N, 2) optional eye-space shifts in x and y."""
    rotations = np.asarray(rotations, np.float64)
    n = rotations.shape[0]
    proj = camera.perspective(fovy, 1.0, near, far)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = rotations
    m[:, 2, 3] = -np.broadcast_to(np.asarray(distance, np.float64), (n,))
    if offsets is not None:
        m[:, :2, 3] = offsets
    return proj @ m


def pose_camera() -> np.ndarray:
    """(4, 4) float64 of the pose fit's fixed camera: proj @ translate(0, 0, -DISTANCE)."""
    m = np.eye(4)
    m[2, 3] = -DISTANCE
    return camera.perspective(FOVY, 1.0, 0.5, 20.0) @ m


def uv_sphere(nu: int = 32, nv: int = 16):
    """(vertices (V, 3), triangles (T, 3) int64, uv (V, 2)) of a unit UV sphere: a
    (nu + 1) x (nv + 1) lattice, u = i / nu around the y axis (seam duplicated), v = j / nv
    from the south pole (v = 0) to the north pole (whose rings are coincident vertices)."""
    faces, (cu, cv) = shapes.parametric_grid(nu, nv, False, False)
    u, v = np.meshgrid(np.arange(cu) / nu, np.arange(cv) / nv, indexing="ij")
    theta, phi = 2.0 * np.pi * u, np.pi * v
    verts = np.stack([np.sin(phi) * np.cos(theta), -np.cos(phi), -np.sin(phi) * np.sin(theta)],
                     -1)
    return verts.reshape(-1, 3), faces, np.stack([u, v], -1).reshape(-1, 2)


def procedural_texture(size: int = 128) -> np.ndarray:
    """(size, 2 size, 3) float64 in [0, 1]: texel (i, j) = tex[j, i] at
    s = (i + 0.5) / (2 size), t = (j + 0.5) / size. Hue bands around the sphere, a 32 x 16
    checkerboard (darker squares) and one-texel grid lines every 8 squares."""
    h, w = size, 2 * size
    s = (np.arange(w) + 0.5) / w
    t = (np.arange(h) + 0.5) / h
    ss, tt = np.meshgrid(s, t)  # (h, w)
    hue = 0.5 + 0.5 * np.cos(2.0 * np.pi * (2.0 * ss[..., None] + np.array([0.0, 1 / 3, 2 / 3])))
    checker = (np.floor(32 * ss) + np.floor(16 * tt)) % 2
    tex = hue * (0.35 + 0.55 * checker[..., None]) + 0.05
    i, j = np.meshgrid(np.arange(w), np.arange(h))
    lines = (i % (w // 4) == 0) | (j % (h // 2) == 0)
    tex[lines] = 1.0
    return np.clip(tex, 0.0, 1.0)


def psnr(a, b, mask=None, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of arrays ``a`` against ``b``, over the pixels where
    ``mask`` (broadcast against the arrays' leading axes) is true."""
    import math

    d2 = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    if mask is not None:
        mask = np.asarray(mask)
        d2 = d2[np.broadcast_to(mask, d2.shape[:mask.ndim])]
    mse = float(d2.mean())
    return math.inf if mse == 0.0 else 10.0 * math.log10(peak * peak / mse)


def first_below(curve, level):
    """The first index where ``curve`` < ``level``, or None."""
    hits = np.flatnonzero(np.asarray(curve) < level)
    return int(hits[0]) if hits.size else None


class Timer:
    """Wall-clock time per named section per iteration::

        timer = Timer()
        with timer("forward"): ...
        timer.summary()  # {"forward": {"mean_ms": ..., "median_ms": ..., "n": ...}, ...}
    """

    def __init__(self):
        self.times = defaultdict(list)

    @contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times[name].append(time.perf_counter() - t0)

    def summary(self) -> dict:
        return {name: {"mean_ms": 1e3 * float(np.mean(t)),
                       "median_ms": 1e3 * float(np.median(t)), "n": len(t)}
                for name, t in self.times.items()}

    @staticmethod
    def merge(summaries) -> dict:
        """Mean of the per-run means and medians, weighted by their counts."""
        out = {}
        for name in {k for s in summaries for k in s}:
            rows = [s[name] for s in summaries if name in s]
            n = sum(r["n"] for r in rows)
            out[name] = {k: sum(r[k] * r["n"] for r in rows) / n
                         for k in ("mean_ms", "median_ms")}
            out[name]["n"] = n
        return out
