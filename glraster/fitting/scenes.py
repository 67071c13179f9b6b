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

__all__ = ["DISPLAY_QUATERNIONS", "DISTANCE", "FOVY", "SUN_DIRECTION", "Timer", "angle_degrees",
           "blob", "cube", "cube_map_directions",
           "cube_symmetries", "first_below", "pose_camera", "procedural_texture",
           "psnr", "quaternion_matrices", "random_quaternions", "studio_cube_map", "uv_sphere",
           "view_matrices"]

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


# --------------------------------------------------------------------------- envmap

# The environment fit's key light: the direction of the sun in the cube map (unit length).
SUN_DIRECTION = np.array([0.45, 0.75, 0.48]) / np.linalg.norm([0.45, 0.75, 0.48])

# GL 4.6 table 8.19 (faces +x, -x, +y, -y, +z, -z): per face the axis and sign of s_c, of
# t_c and of the major axis m; s = (s_c / |m| + 1) / 2, t alike.
_CUBE_FACES = ((2, -1, 1, -1, 0, +1), (2, +1, 1, -1, 0, -1), (0, +1, 2, +1, 1, +1),
               (0, +1, 2, -1, 1, -1), (0, +1, 1, -1, 2, +1), (0, -1, 1, -1, 2, -1))


def cube_map_directions(size: int) -> np.ndarray:
    """(6, size, size, 3) float64 unit directions of the texel centres of a cube map:
    texel (i, j) of face f (``[f, j, i]``) is at s = (i + 0.5) / size, t = (j + 0.5) / size
    (GL table 8.19 inverted: s_c = 2 s - 1, t_c = 2 t - 1, m = 1)."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    tc, sc = np.meshgrid(c, c, indexing="ij")  # (size, size): [j, i]
    out = np.empty((6, size, size, 3))
    for f, (axis_s, sign_s, axis_t, sign_t, axis_m, sign_m) in enumerate(_CUBE_FACES):
        out[f, ..., axis_s] = sign_s * sc
        out[f, ..., axis_t] = sign_t * tc
        out[f, ..., axis_m] = sign_m
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _step(x):
    """The logistic function 1 / (1 + exp(-x)), written with tanh (no overflow)."""
    return 0.5 + 0.5 * np.tanh(0.5 * x)


def studio_cube_map(size: int = 512) -> np.ndarray:
    """(6, size, size, 3) float64 radiance (>= 0, up to ~3 in the sun) of a procedural
    studio sky, y up: a blue gradient from the horizon to the zenith, a warm sun disc with a
    soft halo at :data:`SUN_DIRECTION`, two soft rectangular light panels, and a grey floor
    with a 12 x 12 tile pattern below the horizon (detail at every scale, for the mip
    levels the reflection's footprint picks)."""
    d = cube_map_directions(size)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    up = np.clip(y, 0.0, 1.0)[..., None]
    sky = (1.0 - np.sqrt(up)) * np.array([0.80, 0.84, 0.90]) + np.sqrt(up) * np.array(
        [0.20, 0.38, 0.80])
    # floor: the ground plane y = -1 seen from the origin, tiles of side 1/6
    below = y < 0.0
    safe = np.where(below, -y, 1.0)
    gx, gz = x / safe, z / safe
    tiles = (np.floor(6.0 * gx) + np.floor(6.0 * gz)) % 2
    fade = np.exp(-0.05 * (gx * gx + gz * gz))[..., None]
    floor = (0.18 + 0.14 * tiles[..., None] * fade) * np.array([1.0, 0.92, 0.82])
    env = np.where(below[..., None], floor, sky)
    cos_sun = d @ SUN_DIRECTION
    env += np.array([3.0, 2.7, 2.2]) * np.exp(-(1.0 - cos_sun) / 4e-4)[..., None]
    env += np.array([0.5, 0.45, 0.35]) * np.exp(-(1.0 - cos_sun) / 2e-2)[..., None]
    # panels: |x| > 0.9 side walls, rectangles in (z, y)
    for sign, rgb in ((1.0, (1.6, 1.6, 1.5)), (-1.0, (0.9, 1.0, 1.2))):
        side = sign * x
        zz, yy = z / np.maximum(side, 1e-6), y / np.maximum(side, 1e-6)
        soft = _step((0.35 - np.abs(zz)) / 0.03) * _step((0.25 - np.abs(yy - 0.3)) / 0.03)
        env += np.where(side > 0.0, soft, 0.0)[..., None] * np.array(rgb)
    return env


def blob(nu: int = 128, nv: int = 120, amplitude: float = 0.06, frequency: int = 5):
    """(vertices (V, 3), triangles (T, 3) int64, normals (V, 3)) float64 of a smooth blob:
    :func:`glraster.geometry.shapes.bumpy_sphere` (2 nu nv triangles, 30,720 by default).
    Normals are the area-weighted means of the faces' normals around each vertex; each pole
    (a ring of coincident vertices) gets the mean of its ring."""
    verts, faces = shapes.bumpy_sphere(nu, nv, amplitude=amplitude, frequency=frequency)
    a, b, c = (verts[faces[:, k]] for k in range(3))
    face_n = np.cross(b - a, c - a)  # length = 2 x area
    normals = np.zeros_like(verts)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_n)
    rings = normals.reshape(nu, nv + 1, 3)
    for j in (0, nv):
        rings[:, j] = rings[:, j].sum(axis=0)
    normals = rings.reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return verts, faces, normals
