"""Recover a cube's rotation from one image of it, in JAX.

The problem, restarts, symmetry jumps, loss and schedule of
:mod:`glraster.torch.fitting.pose` (the same random draws for a seed): ``restarts``
quaternions fitted side by side (one instanced draw per iteration) by Adam on the sum of
their mean squared image differences, each normalized before use and after every step;
after the fractions ``jumps`` of the run every restart moves to the best of its 24
symmetric variants (the optimizer keeps its moments). The answer is the restart with the
lowest final loss.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

import glraster.jax as dr
from glraster.fitting.results import PoseFit
from glraster.fitting.scenes import (
    Timer,
    angle_degrees,
    cube,
    cube_symmetries,
    pose_camera,
    random_quaternions,
)
from glraster.jax.fitting.common import adam, multiply, normalized, quaternion_matrices, shade

__all__ = ["fit_pose", "render_pose"]


def render_pose(glctx, q, resolution: int, *, antialias=True, topology=None):
    """(N, R, R, 3) images of the cube turned by each of the (N, 4) quaternions ``q``
    (differentiable in ``q``)."""
    vertices, triangles, colors = cube()
    v = jnp.asarray(vertices, jnp.float32)
    rotated = jnp.einsum("nij,vj->nvi", quaternion_matrices(jnp.asarray(q, jnp.float32)), v)
    clip = jnp.concatenate([rotated, jnp.ones_like(rotated[..., :1])], -1) \
        @ jnp.asarray(pose_camera(), jnp.float32).T
    return shade(glctx, clip, triangles.astype(np.int32), jnp.asarray(colors, jnp.float32),
                 (resolution, resolution), antialias=antialias, topology=topology)


def _normalized64(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def fit_pose(glctx, seed: int, *, resolution: int = 32, restarts: int = 8,
             iterations: int = 300, lr: float = 3e-2, lr_decay: float = 0.03,
             jumps=(0.25, 0.5), antialias: bool = True, progress=None) -> PoseFit:
    """Recover the rotation of ``seed`` (see the module doc). ``jumps``: the fractions of
    the run after which every restart moves to its best symmetric variant (() for none).
    ``progress``: optional callable ``(i, total, label)`` called every iteration."""
    _, triangles, _ = cube()
    topology = (dr.antialias_construct_topology_hash(triangles.astype(np.int32))
                if antialias else None)
    rng = np.random.default_rng(seed)
    target_q = random_quaternions(rng, 1)[0]
    start = random_quaternions(rng, restarts)

    def render(q):
        return render_pose(glctx, q, resolution, antialias=antialias, topology=topology)

    target = render(target_q[None])
    q = jnp.asarray(start, jnp.float32)
    optimizer = adam(lr, lr_decay, iterations)
    state = optimizer.init(q)
    update = jax.jit(optimizer.update)

    def per_restart(q):
        return jnp.mean((render(q) - target) ** 2, axis=(1, 2, 3))

    def total(q):
        each = per_restart(q)
        return jnp.sum(each), each

    loss_and_grad = jax.jit(jax.value_and_grad(total, has_aux=True))
    per_restart_jit = jax.jit(per_restart)

    timer = Timer()
    angles, losses, jumped = [], [], []
    jump_at = sorted({round(f * iterations) for f in jumps} - {0, iterations})
    symmetries = jnp.asarray(cube_symmetries(), jnp.float32)
    for it in range(iterations + 1):
        if it in jump_at:
            with timer("jump"):
                variants = multiply(q[:, None, :], symmetries[None, :, :]).reshape(-1, 4)
                err = per_restart_jit(variants).reshape(restarts, -1)
                choice = np.asarray(jnp.argmin(err, axis=1))
                q = variants.reshape(restarts, -1, 4)[np.arange(restarts), choice]
            jumped.append((it, [int(c) for c in choice]))
        angles.append(angle_degrees(np.asarray(q, np.float64), target_q))
        if it == iterations:  # the loss at the final parameters: no step
            final_loss = np.asarray(per_restart_jit(q), np.float64)
            break
        with timer("forward+backward"):
            (_, each), grad = jax.block_until_ready(loss_and_grad(q))
        with timer("step"):
            updates, state = update(grad, state, q)
            q = jax.block_until_ready(normalized(optax.apply_updates(q, updates)))
        losses.append(np.asarray(each, np.float64))
        if progress is not None:
            best = int(np.argmin(losses[-1]))
            progress(it + 1, iterations, f"seed {seed} best restart {best} angle "
                                         f"{angles[-1][best]:.1f} deg")
    best = int(np.argmin(final_loss))
    return PoseFit(seed=seed, resolution=resolution, iterations=iterations, restarts=restarts,
                   antialias=antialias, target=target_q, start=start,
                   final=_normalized64(q),
                   angle=np.array(angles), loss=np.array(losses).reshape(iterations, restarts),
                   best=best, final_loss=final_loss, jumps=jumped, timing=timer.summary())
