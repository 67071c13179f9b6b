"""Fit a cube's 8 vertex positions and colours to images of the true cube, in JAX.

The problem, start, views, loss and schedule of :mod:`glraster.torch.fitting.cube` (the
same random draws for a seed): each iteration turns both cubes by ``views`` uniformly
random rotations, renders them at ``resolution`` x ``resolution`` through rasterize ->
interpolate -> antialias (one instanced draw of all views), and takes one Adam step on the
mean squared image difference, the learning rate falling from ``lr`` to ``lr * lr_decay``.
The error is the mean distance of the 8 vertices from the true ones.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

import glraster.jax as dr
from glraster.fitting.results import CubeFit
from glraster.fitting.scenes import (
    DISTANCE,
    FOVY,
    Timer,
    cube,
    quaternion_matrices,
    random_quaternions,
    view_matrices,
)
from glraster.jax.fitting.common import adam, clip_positions, shade

__all__ = ["fit_cube", "render_cube"]


def render_cube(glctx, mvp, vertices, colors, tri, resolution: int, *, antialias=True,
                topology=None):
    """(B, R, R, 3) images of the cube under (B, 4, 4) ``mvp`` (JAX arrays, differentiable
    in ``vertices`` (8, 3) and ``colors`` (8, 3))."""
    return shade(glctx, clip_positions(mvp, vertices), tri, colors, (resolution, resolution),
                 antialias=antialias, topology=topology)


def fit_cube(glctx, resolution: int, seed: int, *, iterations: int = 1000, views: int = 4,
             lr: float = 1e-2, lr_decay: float = 0.1, antialias: bool = True,
             progress=None) -> CubeFit:
    """Fit the cube from the random start of ``seed`` (see the module doc).

    glctx: a :class:`glraster.jax.RasterizeGLContext`. antialias: False fits through
    rasterize -> interpolate only (no visibility gradient). progress: optional callable
    ``(i, total, label)``, called every iteration. Timing sections: "target" (the true
    cube's images), "forward+backward" (the loss and its gradient, one jitted call: the
    backward recomputes the forward, see :mod:`glraster.jax.bridge`), "step" (optax's
    Adam update).
    """
    vertices, triangles, colors = cube()
    tri = triangles.astype(np.int32)
    topology = dr.antialias_construct_topology_hash(tri) if antialias else None
    true_pos = jnp.asarray(vertices, jnp.float32)
    true_col = jnp.asarray(colors, jnp.float32)
    rng = np.random.default_rng(seed)
    start_pos = vertices + rng.uniform(-0.5, 0.5, vertices.shape)
    start_col = rng.uniform(0.0, 1.0, colors.shape)
    params = (jnp.asarray(start_pos, jnp.float32), jnp.asarray(start_col, jnp.float32))
    optimizer = adam(lr, lr_decay, iterations)
    state = optimizer.init(params)
    update = jax.jit(optimizer.update)

    def render(mvp, pos, col):
        return render_cube(glctx, mvp, pos, col, tri, resolution, antialias=antialias,
                           topology=topology)

    def loss_of(p, mvp, target):
        return jnp.mean((render(mvp, *p) - target) ** 2)

    render_target = jax.jit(lambda mvp: render(mvp, true_pos, true_col))
    loss_and_grad = jax.jit(jax.value_and_grad(loss_of))

    timer = Timer()
    error, color_error, losses = [], [], []

    def measure(p):
        pos, col = (np.asarray(a, np.float64) for a in p)
        error.append(float(np.linalg.norm(pos - vertices, axis=1).mean()))
        color_error.append(float(np.abs(col - colors).mean()))

    for it in range(iterations):
        measure(params)
        mvp = jnp.asarray(view_matrices(quaternion_matrices(random_quaternions(rng, views)),
                                        distance=DISTANCE, fovy=FOVY), jnp.float32)
        with timer("target"):
            target = jax.block_until_ready(render_target(mvp))
        with timer("forward+backward"):
            loss, grads = jax.block_until_ready(loss_and_grad(params, mvp, target))
        with timer("step"):
            updates, state = update(grads, state, params)
            params = jax.block_until_ready(optax.apply_updates(params, updates))
        losses.append(float(loss))
        if progress is not None:
            progress(it + 1, iterations, f"{resolution}x{resolution} seed {seed} "
                                         f"error {error[-1]:.4f}")
    measure(params)
    return CubeFit(resolution=resolution, seed=seed, iterations=iterations, views=views,
                   antialias=antialias, error=np.array(error), color_error=np.array(color_error),
                   loss=np.array(losses), true_pos=vertices, true_col=colors,
                   start_pos=start_pos, start_col=start_col,
                   final_pos=np.asarray(params[0], np.float64),
                   final_col=np.asarray(params[1], np.float64), timing=timer.summary())
