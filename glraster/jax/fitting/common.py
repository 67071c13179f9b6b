"""What the JAX fits share: the session, quaternions and clip positions on JAX arrays, the
shading path rasterize -> interpolate (-> antialias), and Adam with the torch fits'
schedule (optax)."""

from __future__ import annotations

from contextlib import contextmanager

import jax.numpy as jnp
import numpy as np
import optax

import glraster.jax as dr

__all__ = ["adam", "clip_positions", "multiply", "normalized", "quaternion_matrices",
           "session", "shade"]


@contextmanager
def session(*, backend: str | None = None):
    """A :class:`glraster.jax.RasterizeGLContext` on a new OpenGL context of ``backend``,
    released on leaving."""
    from glraster.gpu.context import Context

    ctx = Context(backend=backend)
    try:
        yield dr.RasterizeGLContext(context=ctx)
    finally:
        ctx.release()


def normalized(q):
    """q / |q| along the last axis."""
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_matrices(q):
    """(..., 3, 3) rotation matrices of (..., 4) quaternions (normalized here first)."""
    q = normalized(q)
    w, x, y, z = (q[..., k] for k in range(4))
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]
    return jnp.stack(rows, -1).reshape(q.shape[:-1] + (3, 3))


def multiply(a, b):
    """Hamilton product of quaternions (..., 4): R(a b) = R(a) R(b)."""
    aw, ax, ay, az = (a[..., k] for k in range(4))
    bw, bx, by, bz = (b[..., k] for k in range(4))
    return jnp.stack([aw * bw - ax * bx - ay * by - az * bz,
                      aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx,
                      aw * bz + ax * by - ay * bx + az * bw], -1)


def clip_positions(mvp, vertices):
    """(N, V, 4) clip-space positions of (V, 3) ``vertices`` under (N, 4, 4) ``mvp``."""
    homogeneous = jnp.concatenate([vertices, jnp.ones_like(vertices[:, :1])], axis=1)
    return jnp.einsum("bij,vj->bvi", mvp, homogeneous)


def shade(glctx, clip, tri: np.ndarray, colors, resolution, *, antialias=True, topology=None):
    """(B, H, W, C) image of vertex ``colors`` (V, C) at clip positions ``clip`` (B, V, 4),
    background 0; with ``antialias`` the silhouettes are blended (the positions'
    visibility gradient)."""
    rast, _ = dr.rasterize(glctx, clip, tri, resolution, grad_db=False)
    image, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    if antialias:
        image = dr.antialias(image, rast, clip, tri, topology, glctx=glctx)
    return image


def adam(lr: float, lr_decay: float, iterations: int) -> optax.GradientTransformation:
    """Adam (torch's defaults: b1 0.9, b2 0.999, eps 1e-8) with the learning rate falling
    exponentially from ``lr`` to ``lr * lr_decay`` over ``iterations`` steps, as the
    torch fits' LambdaLR schedule."""
    return optax.adam(lambda step: lr * lr_decay ** (step / max(iterations, 1)))
