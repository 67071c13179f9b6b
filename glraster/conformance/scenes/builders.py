"""Recipe builders: turn a catalog entry's parameters into clip-space geometry.

Each builder takes the scene ``resolution`` (height, width) and keyword parameters from
the catalog file, and returns ``(pos, tri)``: pos (V, 4) float64 clip-space positions,
tri (T, 3) int64 vertex indices. Randomness always comes from ``numpy.random.default_rng``
with the recipe's ``seed``, so a recipe reproduces the same scene everywhere.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from glraster.errors import ArgumentError
from glraster.geometry import shapes as meshes
from glraster.geometry.camera import look_at, orthographic, perspective
from glraster.geometry.transforms import rotation, to_clip
from glraster.geometry.window import window_to_clip

BUILDERS: dict[str, Callable] = {}


def builder(fn: Callable) -> Callable:
    BUILDERS[fn.__name__] = fn
    return fn


def _camera_matrix(resolution, camera: dict) -> np.ndarray:
    h, w = resolution
    kind = camera.get("kind", "perspective")
    view = look_at(camera.get("eye", (0, 0, 3)), camera.get("target", (0, 0, 0)),
                   camera.get("up", (0, 1, 0)))
    if kind == "perspective":
        proj = perspective(camera.get("fovy", 45.0), w / h, camera.get("near", 0.1),
                           camera.get("far", 100.0))
    elif kind == "orthographic":
        half_h = camera.get("half_height", 1.5)
        half_w = half_h * w / h
        proj = orthographic(-half_w, half_w, -half_h, half_h, camera.get("near", 0.1),
                            camera.get("far", 100.0))
    else:
        raise ArgumentError(
            "kind", f"camera kind must be 'perspective' or 'orthographic', got {kind!r}")
    return proj @ view


@builder
def clip(resolution, pos, tri):
    """Explicit clip-space vertices and triangles, as written in the catalog."""
    return np.asarray(pos, dtype=np.float64), np.asarray(tri, dtype=np.int64)


@builder
def window(resolution, xy, tri, z=0.0, w=1.0):
    """Vertices given in window pixels (GL convention), optional per-vertex NDC z and clip w."""
    return window_to_clip(np.asarray(xy, dtype=np.float64), resolution, z, w), \
        np.asarray(tri, dtype=np.int64)


@builder
def mesh(resolution, mesh, camera, model=None):
    """A procedural mesh seen through a camera.

    mesh: {"kind": "icosphere"|"torus"|"bumpy_sphere"|"plane_grid"|"box", ...arguments}.
    camera: {"kind": "perspective"|"orthographic", "eye", "target", "up", "fovy", "near",
    "far", "half_height"}. model: optional list of {"axis": [x, y, z], "angle": deg}
    rotations and {"translate": [x, y, z]} steps applied in order.
    """
    args = dict(mesh)
    kind = args.pop("kind")
    gen = {"icosphere": meshes.icosphere, "torus": meshes.torus,
           "bumpy_sphere": meshes.bumpy_sphere, "plane_grid": meshes.plane_grid,
           "box": meshes.box}.get(kind)
    if gen is None:
        raise ArgumentError("kind", f"unknown mesh kind {kind!r}")
    verts, faces = gen(**args)
    m = np.eye(4)
    for step in model or []:
        if "translate" in step:
            t = np.eye(4)
            t[:3, 3] = step["translate"]
            m = t @ m
        else:
            m = rotation(step["axis"], step["angle"]) @ m
    return to_clip(verts, _camera_matrix(resolution, camera) @ m), faces


@builder
def fan(resolution, center, radius, count, w_center=1.0, w_rim=1.0, phase_deg=0.0):
    """Triangle fan: ``count`` triangles around ``center`` (window pixels) sharing edges.

    Rim vertices lie on a circle of ``radius`` pixels; w_center / w_rim set clip w."""
    ang = np.radians(phase_deg) + 2 * np.pi * np.arange(count) / count
    rim = np.stack([center[0] + radius * np.cos(ang), center[1] + radius * np.sin(ang)], 1)
    xy = np.concatenate([np.asarray(center, dtype=np.float64)[None], rim])
    w = np.concatenate([[w_center], np.full(count, w_rim)])
    z = np.concatenate([[0.0], np.linspace(-0.5, 0.5, count)])
    i = np.arange(count)
    tri = np.stack([np.zeros(count, dtype=np.int64), 1 + i, 1 + (i + 1) % count], 1)
    return window_to_clip(xy, resolution, z, w), tri


@builder
def window_grid(resolution, origin, cell, nx, ny, w_range=(1.0, 1.0), seed=0):
    """nx x ny grid of pixel-space cells starting at ``origin`` (window pixels), each cell
    2 triangles, cell size ``cell`` pixels. Vertex w uniform in w_range (seeded)."""
    faces, (cu, cv) = meshes.parametric_grid(nx, ny, False, False)
    gx = origin[0] + cell * np.arange(cu)
    gy = origin[1] + cell * np.arange(cv)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    xy = np.stack([xx.ravel(), yy.ravel()], 1)
    rng = np.random.default_rng(seed)
    w = rng.uniform(w_range[0], w_range[1], len(xy)) if w_range[0] != w_range[1] \
        else np.full(len(xy), float(w_range[0]))
    z = rng.uniform(-0.9, 0.9, len(xy))
    return window_to_clip(xy, resolution, z, w), faces


def _triangles_from_centers(rng, centers, sizes, w_lo, w_hi):
    """Random triangles around window-space centers: (3n, 2) xy, (3n,) w, (n, 3) tri."""
    n = len(centers)
    ang = rng.uniform(0, 2 * np.pi, (n, 3))
    rad = sizes[:, None] * rng.uniform(0.4, 1.0, (n, 3))
    xy = (centers[:, None, :] + np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1))
    w = np.exp(rng.uniform(np.log(w_lo), np.log(w_hi), (n, 3)))
    tri = np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    return xy.reshape(-1, 2), w.reshape(-1), tri


@builder
def soup(resolution, count, size_px, w_range=(1.0, 1.0), region=None, seed=0):
    """``count`` independent random triangles (no shared vertices).

    size_px: (min, max) circumradius in pixels, log-uniform. region: (x0, y0, x1, y1)
    window-space box for the centers (default the whole viewport). w_range: clip w
    per vertex, log-uniform. NDC z uniform in (-0.95, 0.95)."""
    h, w_px = resolution
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = region if region is not None else (0, 0, w_px, h)
    centers = np.stack([rng.uniform(x0, x1, count), rng.uniform(y0, y1, count)], 1)
    sizes = np.exp(rng.uniform(np.log(size_px[0]), np.log(size_px[1]), count))
    xy, w, tri = _triangles_from_centers(rng, centers, sizes, *w_range)
    z = rng.uniform(-0.95, 0.95, len(xy))
    return window_to_clip(xy, resolution, z, w), tri


@builder
def slivers(resolution, count, length_px, aspects, seed=0, w_range=(1.0, 1.0)):
    """Needle triangles: base ``length_px`` pixels long, height length/aspect, with aspect
    log-spaced over ``aspects`` = (min, max); random direction, center and w."""
    h, w_px = resolution
    rng = np.random.default_rng(seed)
    asp = np.exp(np.linspace(np.log(aspects[0]), np.log(aspects[1]), count))
    c = np.stack([rng.uniform(0.2 * w_px, 0.8 * w_px, count),
                  rng.uniform(0.2 * h, 0.8 * h, count)], 1)
    ang = rng.uniform(0, np.pi, count)
    d = np.stack([np.cos(ang), np.sin(ang)], 1)
    nrm = np.stack([-d[:, 1], d[:, 0]], 1)
    half = length_px / 2
    apex_t = rng.uniform(-0.8, 0.8, count)[:, None]
    a = c - half * d
    b = c + half * d
    apex = c + apex_t * half * d + (length_px / asp)[:, None] * nrm
    xy = np.stack([a, b, apex], 1).reshape(-1, 2)
    w = np.exp(rng.uniform(np.log(w_range[0]), np.log(w_range[1]), 3 * count))
    z = rng.uniform(-0.9, 0.9, 3 * count)
    tri = np.arange(3 * count, dtype=np.int64).reshape(count, 3)
    return window_to_clip(xy, resolution, z, w), tri


@builder
def guard_band(resolution, count, reach_ndc, seed=0):
    """Triangles with one or two vertices far outside the viewport (|ndc| up to
    ``reach_ndc``) and the rest inside, so that each crosses the viewport and the
    rasterizer must clip it against its guard band."""
    rng = np.random.default_rng(seed)
    pos = []
    for k in range(count):
        far = np.exp(rng.uniform(np.log(2.0), np.log(reach_ndc), 2))
        ang = rng.uniform(0, 2 * np.pi, 2)
        outside = np.stack([far * np.cos(ang), far * np.sin(ang)], 1)
        inside = rng.uniform(-0.8, 0.8, (1, 2))
        xy = np.concatenate([inside, outside[: 1 + k % 2], rng.uniform(-0.8, 0.8, (1, 2))])[:3]
        w = rng.uniform(0.5, 2.0, 3)
        z = rng.uniform(-0.9, 0.9, 3)
        pos.append(np.stack([xy[:, 0] * w, xy[:, 1] * w, z * w, w], 1))
    return np.concatenate(pos), np.arange(3 * count, dtype=np.int64).reshape(count, 3)


@builder
def eye_space(resolution, triangles, fovy=60.0, near=0.5, far=50.0):
    """Triangles given directly in eye space (camera at the origin looking down -z),
    projected with a perspective camera. Used for near-plane crossings and for vertices
    behind the camera (eye z > 0, hence clip w < 0)."""
    h, w = resolution
    v = np.asarray(triangles, dtype=np.float64).reshape(-1, 3)
    pos = to_clip(v, perspective(fovy, w / h, near, far))
    return pos, np.arange(len(v), dtype=np.int64).reshape(-1, 3)


@builder
def w_ratio(resolution, count, ratios, seed=0):
    """Triangles inside the viewport whose vertices have clip w spanning ``ratios``
    (e.g. [1e-3, 1e3]): one vertex at w = 1, one at w = r, one at w = 1/r, r log-spaced
    from 1 to ratios[1]."""
    rng = np.random.default_rng(seed)
    h, wp = resolution
    r = np.exp(np.linspace(0.0, np.log(ratios[1]), count))
    pos = []
    for k in range(count):
        cx, cy = rng.uniform(0.2 * wp, 0.8 * wp), rng.uniform(0.2 * h, 0.8 * h)
        size = rng.uniform(0.15, 0.4) * min(h, wp)
        ang = rng.uniform(0, 2 * np.pi) + np.array([0, 2.1, 4.2])
        xy = np.stack([cx + size * np.cos(ang), cy + size * np.sin(ang)], 1)
        w = rng.permutation(np.array([1.0, r[k], 1.0 / r[k]]))
        pos.append(window_to_clip(xy, resolution, rng.uniform(-0.9, 0.9, 3), w))
    return np.concatenate(pos), np.arange(3 * count, dtype=np.int64).reshape(count, 3)


@builder
def depth_fight(resolution):
    """Depth ties and near-ties: a triangle drawn twice with identical vertices (the
    earlier must win), a quad split two ways in one plane, and a pair of planes 1e-7
    apart in NDC z drawn far-first then near-first."""
    h, w = resolution
    s = np.array([w, h], dtype=np.float64)
    parts_xy, parts_z, parts_w = [], [], []
    # identical triangle twice, perspective
    t = np.array([[0.05, 0.05], [0.45, 0.1], [0.2, 0.45]]) * s
    for _ in range(2):
        parts_xy.append(t)
        parts_z.append(np.array([0.1, 0.3, -0.2]))
        parts_w.append(np.array([1.0, 2.5, 0.7]))
    # one plane, two triangulations (diagonals crossing): same depth plane
    q = np.array([[0.55, 0.05], [0.95, 0.05], [0.95, 0.45], [0.55, 0.45]]) * s
    qz = np.array([0.2, 0.2, -0.4, -0.4])
    for idx in ([0, 1, 2], [0, 2, 3], [0, 1, 3], [1, 2, 3]):
        parts_xy.append(q[idx])
        parts_z.append(qz[idx])
        parts_w.append(np.ones(3))
    # two nearly coincident planes, far one first then the near one
    p = np.array([[0.1, 0.55], [0.9, 0.6], [0.5, 0.95]]) * s
    base = np.array([0.3, 0.1, 0.2])
    parts_xy += [p, p]
    parts_z += [base + 1e-7, base]
    parts_w += [np.ones(3), np.ones(3)]
    xy = np.concatenate(parts_xy)
    pos = window_to_clip(xy, resolution, np.concatenate(parts_z), np.concatenate(parts_w))
    return pos, np.arange(len(xy), dtype=np.int64).reshape(-1, 3)
