"""Procedural triangle meshes for the scene catalog.

Every function returns ``(vertices, faces)``: vertices (V, 3) float64 world positions,
faces (T, 3) int64 vertex indices, counter-clockwise seen from outside. Results depend only
on the arguments, so catalog scenes are reproducible without shipping vertex data.
"""

from __future__ import annotations

import numpy as np

from glraster.errors import ArgumentError


def icosphere(level: int, radius: float = 1.0):
    """Icosahedron subdivided ``level`` times (20 * 4**level faces), projected on a sphere."""
    if level < 0:
        raise ArgumentError("level", f"level must be >= 0, got {level}")
    t = (1.0 + 5.0 ** 0.5) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
             (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
             (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
             (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
             (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
             (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in verts]
    for _ in range(level):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts) * radius, np.array(faces, dtype=np.int64)


def parametric_grid(nu: int, nv: int, wrap_u: bool, wrap_v: bool):
    """Faces of an nu x nv grid of quads (2 triangles each) over a (nu', nv') vertex lattice.

    With wrap_u the lattice has nu columns and the last column connects to the first
    (otherwise nu + 1 columns); same for v. Returns (faces (T, 3) int64, lattice shape).
    """
    cu = nu if wrap_u else nu + 1
    cv = nv if wrap_v else nv + 1
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % cu
    j1 = (j + 1) % cv
    a = i * cv + j
    b = i1 * cv + j
    c = i1 * cv + j1
    d = i * cv + j1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return faces.astype(np.int64), (cu, cv)


def torus(major: float, minor: float, nu: int, nv: int):
    """Torus around the y axis: nu segments around the ring, nv around the tube."""
    faces, (cu, cv) = parametric_grid(nu, nv, True, True)
    u = 2 * np.pi * np.arange(cu) / cu
    v = 2 * np.pi * np.arange(cv) / cv
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(vv)
    verts = np.stack([r * np.cos(uu), minor * np.sin(vv), r * np.sin(uu)], -1).reshape(-1, 3)
    return verts, faces


def bumpy_sphere(nu: int, nv: int, amplitude: float = 0.08, frequency: int = 9):
    """UV sphere with radial bumps: nu longitudes x nv latitudes, 2 * nu * nv faces.

    The poles are rings of coincident vertices (degenerate triangles there are intended:
    they must produce no fragments)."""
    faces, (cu, cv) = parametric_grid(nu, nv, True, False)
    theta = 2 * np.pi * np.arange(cu) / cu
    phi = np.pi * np.arange(cv) / nv
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    r = 1.0 + amplitude * np.sin(frequency * tt) * np.sin(frequency * pp)
    verts = np.stack([r * np.sin(pp) * np.cos(tt), r * np.cos(pp),
                      r * np.sin(pp) * np.sin(tt)], -1).reshape(-1, 3)
    return verts, faces


def plane_grid(nx: int, ny: int, size_x: float, size_y: float, jitter: float = 0.0,
               seed: int = 0):
    """Grid of nx x ny quads in the z = 0 plane centered at the origin.

    jitter: interior vertices move by up to jitter * cell size (uniform, seeded)."""
    faces, (cu, cv) = parametric_grid(nx, ny, False, False)
    x = np.linspace(-size_x / 2, size_x / 2, cu)
    y = np.linspace(-size_y / 2, size_y / 2, cv)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    if jitter:
        rng = np.random.default_rng(seed)
        dx = rng.uniform(-jitter, jitter, xx.shape) * size_x / nx
        dy = rng.uniform(-jitter, jitter, yy.shape) * size_y / ny
        dx[[0, -1], :] = 0
        dx[:, [0, -1]] = 0
        dy[[0, -1], :] = 0
        dy[:, [0, -1]] = 0
        xx, yy = xx + dx, yy + dy
    verts = np.stack([xx, yy, np.zeros_like(xx)], -1).reshape(-1, 3)
    return verts, faces


def box(size=(1.0, 1.0, 1.0)):
    """Axis-aligned box centered at the origin, 12 faces."""
    sx, sy, sz = (np.asarray(size, dtype=np.float64) / 2)
    verts = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                     dtype=np.int64)
    return verts, faces
