"""Fit a cube's 8 vertex positions and colours to images of the true cube.

The setup (glraster's own, after the idea of nvdiffrast's cube sample): the unit cube
(vertices at +-0.5, 12 triangles, :func:`glraster.geometry.shapes.box`) with one colour per
vertex, 0.15 + 0.7 (x + 0.5, y + 0.5, z + 0.5) (an RGB cube kept off the black
background). The start moves every vertex coordinate by a uniform offset in [-0.5, 0.5]
(a mean vertex error of about 0.5) and draws the colours uniformly in [0, 1]. Each
iteration turns both cubes by ``views`` rotations drawn uniformly (a new set every
iteration), renders them at ``resolution`` x ``resolution`` pixels through rasterize ->
interpolate -> antialias (instanced: one draw of all views; the true cube's images of
:data:`TARGET_BATCH` iterations in one call), and takes one Adam step on the mean squared
image difference; the learning rate falls exponentially from ``lr`` to
``lr * lr_decay`` over the run. The error is the mean distance of the 8 vertices from the
true ones.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from glraster.fitting.results import CubeFit
from glraster.fitting.scenes import DISPLAY_QUATERNIONS, DISTANCE, FOVY, cube
from glraster.torch.fitting.common import (
    Timer,
    clip_positions,
    descend,
    quaternion_matrices,
    random_quaternions,
    view_matrices,
)
from glraster.torch.fitting.render import shade, topology_hash

__all__ = ["CubeFit", "cube", "display_views", "fit_cube", "render_cube"]

# Iterations whose target images are rendered together: the targets do not depend on the
# parameters, and one call for many images costs about what one call for 4 does.
TARGET_BATCH = 32


def display_views() -> torch.Tensor:
    """(2, 4, 4) float32 view matrices of the pictures."""
    rot = quaternion_matrices(DISPLAY_QUATERNIONS)
    return torch.tensor(view_matrices(rot, distance=DISTANCE, fovy=FOVY), dtype=torch.float32)


def render_cube(glctx, mvp, vertices, colors, tri, resolution: int, *, antialias=True,
                topology=None):
    """(B, R, R, 3) images of the cube (torch tensors in, autograd through)."""
    image, _ = shade(glctx, clip_positions(mvp, vertices), tri, colors,
                     (resolution, resolution), antialias=antialias, topology=topology)
    return image


def fit_cube(glctx, resolution: int, seed: int, *, iterations: int = 1000, views: int = 4,
             lr: float = 1e-2, lr_decay: float = 0.1, antialias: bool = True,
             progress=None) -> CubeFit:
    """Fit the cube from the random start of ``seed`` (see the module doc).

    glctx: a :class:`glraster.torch.RasterizeGLContext`. antialias: False fits through
    rasterize -> interpolate only (no visibility gradient). progress: optional callable
    ``(i, total, label)``, called every iteration.
    """
    vertices, triangles, colors = cube()
    tri = torch.tensor(triangles, dtype=torch.int32)
    topology = topology_hash(tri) if antialias else None
    true_pos = torch.tensor(vertices, dtype=torch.float32)
    true_col = torch.tensor(colors, dtype=torch.float32)
    rng = np.random.default_rng(seed)
    start_pos = vertices + rng.uniform(-0.5, 0.5, vertices.shape)
    start_col = rng.uniform(0.0, 1.0, colors.shape)
    pos = torch.tensor(start_pos, dtype=torch.float32, requires_grad=True)
    col = torch.tensor(start_col, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([pos, col], lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda it: lr_decay ** (it / max(iterations, 1)))
    timer = Timer()
    # every iteration's views drawn at once (the same stream of draws, the same matrices)
    mvps = torch.tensor(view_matrices(quaternion_matrices(random_quaternions(
        rng, views * iterations)), distance=DISTANCE, fovy=FOVY),
        dtype=torch.float32).reshape(iterations, views, 4, 4)
    states, losses = [(pos.detach().clone(), col.detach().clone())], []
    # the OpenGL context current for the whole loop: the ops' own blocks switch nothing
    with glctx.context:
        for it, mvp in enumerate(mvps):
            if it % TARGET_BATCH == 0:
                start = time.perf_counter()
                targets = _targets(glctx, mvps[it:it + TARGET_BATCH], true_pos, true_col,
                                   tri, resolution, antialias, topology)
                count = len(targets) // views  # (the time shared among their iterations)
                timer.times["target"] += [(time.perf_counter() - start) / count] * count
            target = targets[(it % TARGET_BATCH) * views:][:views]
            with timer("forward"):
                image = render_cube(glctx, mvp, pos, col, tri, resolution,
                                    antialias=antialias, topology=topology)
                loss = torch.mean((image - target) ** 2)
            descend(timer, loss, opt, schedule)
            losses.append(loss.detach())
            states.append((pos.detach().clone(), col.detach().clone()))
            if progress is not None:
                progress(it + 1, iterations, f"{resolution}x{resolution} seed {seed} "
                                             f"error {_errors([states[-2][0]], true_pos)[0]:.4f}")
    # the errors of every state at once (the same bits as one state at a time)
    error = _errors([p for p, _ in states], true_pos)
    color_error = (torch.stack([c for _, c in states]) - true_col).abs().mean(dim=(1, 2))
    return CubeFit(resolution=resolution, seed=seed, iterations=iterations, views=views,
                   antialias=antialias, error=np.array(error),
                   color_error=np.array(color_error.tolist()),
                   loss=np.array(torch.stack(losses).tolist() if losses else []),
                   true_pos=vertices, true_col=colors,
                   start_pos=start_pos, start_col=start_col,
                   final_pos=pos.detach().double().numpy(),
                   final_col=col.detach().double().numpy(), timing=timer.summary())


def _targets(glctx, mvps, true_pos, true_col, tri, resolution: int, antialias, topology):
    """(N V, R, R, 3) target images of the (N, V, 4, 4) views of N iterations, rendered in
    one call of each op (no gradient): every image is computed on its own, so each is bit
    for bit the one of a call on its iteration's views alone."""
    with torch.no_grad():
        clip = torch.cat([clip_positions(mvp, true_pos) for mvp in mvps])
        image, _ = shade(glctx, clip, tri, true_col, (resolution, resolution),
                         antialias=antialias, topology=topology)
    return image


def _errors(positions, true_pos) -> list[float]:
    """The mean vertex distance from ``true_pos`` of each of ``positions`` ((8, 3) each)."""
    return (torch.stack(positions) - true_pos).norm(dim=2).mean(dim=1).tolist()
