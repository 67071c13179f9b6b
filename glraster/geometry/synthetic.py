"""Procedural triangle sets used by the demo, the tests and the benchmark.

Every function returns ``(pos, tri)``: pos (V, 4) float32 clip-space positions, tri (T, 3)
int32 indices, deterministic for a given ``seed``.
"""

from __future__ import annotations

import numpy as np


def _clip_from_ndc(ndc: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 3) NDC and (N,) w -> (N, 4) float32 clip-space positions (x w, y w, z w, w)."""
    return np.concatenate([ndc * w[:, None], w[:, None]], axis=1).astype(np.float32)


def random_soup(count: int, seed: int = 0, w_range=(0.2, 20.0), size: float | None = None):
    """``count`` independent triangles with every vertex inside the viewport.

    size: None for vertices uniform over NDC [-1, 1]^2; else the NDC standard deviation of
    each vertex around a random center (small sizes give tiny and sliver triangles).
    NDC z is uniform in (-0.99, 0.99); w is log-uniform in ``w_range``.
    """
    rng = np.random.default_rng(seed)
    if size is None:
        ndc = rng.uniform(-1, 1, (count, 3, 3))
    else:
        centers = rng.uniform(-1, 1, (count, 1, 3))
        ndc = np.clip(centers + rng.normal(0, size, (count, 3, 3)), -1, 1)
    ndc[..., 2] = rng.uniform(-0.99, 0.99, (count, 3))
    w = np.exp(rng.uniform(np.log(w_range[0]), np.log(w_range[1]), count * 3))
    pos = _clip_from_ndc(ndc.reshape(-1, 3), w)
    return pos, np.arange(3 * count, dtype=np.int32).reshape(count, 3)


def grid(nx: int, ny: int, seed: int = 0, jitter: float = 0.3, w_range=(1.0, 1.0)):
    """A (nx x ny)-cell grid over NDC [-1, 1]^2, two triangles per cell, shared edges.

    Inner vertices move by up to ``jitter`` cells; w varies smoothly across the grid
    within ``w_range`` (the same w at a shared vertex, so edges stay shared).
    """
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.linspace(-1, 1, nx + 1), np.linspace(-1, 1, ny + 1))
    ndc = np.stack([xs, ys, np.zeros_like(xs)], -1)
    inner = (slice(1, -1), slice(1, -1))
    cell = np.array([2.0 / nx, 2.0 / ny])
    ndc[inner + (slice(0, 2),)] += rng.uniform(-jitter, jitter, ndc[inner + (slice(0, 2),)].shape) * cell
    ndc[..., 2] = 0.5 * xs * ys
    t = (xs + 1) / 2
    w = w_range[0] + (w_range[1] - w_range[0]) * t
    pos = _clip_from_ndc(ndc.reshape(-1, 3), w.reshape(-1))
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    v00 = (j * (nx + 1) + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + nx + 1, v00 + nx + 2
    tri = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return pos, tri.astype(np.int32)


def fan(count: int, center=(0.0, 0.0), radius: float = 0.9, w: float = 1.0):
    """``count`` triangles around one center vertex (every edge is shared but the rim)."""
    angles = np.linspace(0, 2 * np.pi, count, endpoint=False)
    rim = np.stack([center[0] + radius * np.cos(angles), center[1] + radius * np.sin(angles),
                    np.zeros(count)], 1)
    ndc = np.concatenate([[[center[0], center[1], 0.0]], rim])
    pos = _clip_from_ndc(ndc, np.full(len(ndc), w))
    k = np.arange(count)
    tri = np.stack([np.zeros(count, int), 1 + k, 1 + (k + 1) % count], 1)
    return pos, tri.astype(np.int32)


def pixel_aligned_mesh(resolution, step: int = 8):
    """A grid whose vertices sit exactly on pixel centers of ``resolution`` (H, W), w = 1:
    many pixel centers lie exactly on edges, the hard case for a fill rule."""
    height, width = resolution
    xs = (np.arange(0, width, step) + 0.5) / width * 2 - 1
    ys = (np.arange(0, height, step) + 0.5) / height * 2 - 1
    gx, gy = np.meshgrid(xs, ys)
    ny, nx = gx.shape
    ndc = np.stack([gx, gy, np.zeros_like(gx)], -1).reshape(-1, 3)
    pos = _clip_from_ndc(ndc, np.ones(len(ndc)))
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    v00 = (j * nx + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + nx, v00 + nx + 1
    tri = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return pos, tri.astype(np.int32)
