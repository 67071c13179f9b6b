"""Recover a procedural texture on a sphere from images, with and without mipmaps, in JAX.

The scene, views, supersampled targets, loss, schedule and evaluation of
:mod:`glraster.torch.fitting.texture` (the same random draws for a seed): every
iteration takes ``views`` of a pool of ``pool`` views, renders the texture being fitted
through rasterize -> interpolate (uv, and uv_da from ``diff_attrs``) -> texture and takes
an Adam step on the mean squared difference over the pixels the sphere covers completely;
the texture starts grey (0.5) and is clamped to [0, 1] after every step. ``mip=True``
looks it up with linear-mipmap-linear and ``uv_da``, ``mip=False`` with linear.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import optax

import glraster.jax as dr
from glraster.fitting.results import TextureFit
from glraster.fitting.scenes import (
    Timer,
    procedural_texture,
    psnr,
    quaternion_matrices,
    random_quaternions,
    uv_sphere,
    view_matrices,
)
from glraster.jax.fitting.common import adam, clip_positions

__all__ = ["Views", "fit_texture", "make_data", "make_views", "render_texture"]

FOVY = 40.0


@dataclass
class Views:
    """A set of views and their target images."""

    mvp: jax.Array        # (N, 4, 4) float32
    target: jax.Array     # (N, H, W, 3)
    mask: jax.Array       # (N, H, W) bool: pixels the sphere covers completely
    distance: np.ndarray  # (N,)


def _mesh():
    verts, faces, uv = uv_sphere()
    return (jnp.asarray(verts, jnp.float32), faces.astype(np.int32),
            jnp.asarray(uv, jnp.float32))


def render_texture(glctx, mvp, tex, resolution: int, *, mip: bool, mesh=None):
    """(N, R, R, C) images of ``tex`` (1, Ht, Wt, C) on the sphere under the (N, 4, 4)
    ``mvp`` and the (N, R, R) coverage; mip: linear-mipmap-linear with uv_da, else linear.
    Differentiable in ``tex``."""
    verts, tri, uv = mesh or _mesh()
    clip = clip_positions(mvp, verts)
    rast, rast_db = dr.rasterize(glctx, clip, tri, (resolution, resolution), grad_db=mip)
    covered = rast[..., 3] > 0
    if mip:
        uv_img, uv_da = dr.interpolate(uv, rast, tri, rast_db=rast_db, diff_attrs="all",
                                       glctx=glctx)
        out = dr.texture(tex, uv_img, uv_da, filter_mode="linear-mipmap-linear", glctx=glctx)
    else:
        uv_img, _ = dr.interpolate(uv, rast, tri, glctx=glctx)
        out = dr.texture(tex, uv_img, filter_mode="linear", glctx=glctx)
    return out * covered[..., None], covered


def make_views(glctx, rng, n: int, resolution: int, tex, *, supersample: int = 4,
               distances=(3.0, 10.0), chunk: int = 4) -> Views:
    """``n`` random views and their supersampled targets of the true ``tex`` (1, Ht, Wt, 3)."""
    mesh = _mesh()
    rotations = quaternion_matrices(random_quaternions(rng, n))
    distance = rng.uniform(*distances, n)
    mvp = jnp.asarray(view_matrices(rotations, distance=distance, fovy=FOVY), jnp.float32)
    targets, masks = [], []
    big = resolution * supersample
    for k in range(0, n, chunk):
        image, covered = render_texture(glctx, mvp[k:k + chunk], tex, big, mip=True,
                                        mesh=mesh)
        b = image.shape[0]
        pooled = image.reshape(b, resolution, supersample, resolution, supersample, -1)
        targets.append(pooled.mean(axis=(2, 4)))
        cov = covered.reshape(b, resolution, supersample, resolution, supersample)
        masks.append(cov.all(axis=4).all(axis=2))
    return Views(mvp=mvp, target=jnp.concatenate(targets), mask=jnp.concatenate(masks),
                 distance=distance)


def masked_mse(image, target, mask):
    m = mask[..., None].astype(image.dtype)
    return jnp.sum(m * (image - target) ** 2) / (jnp.sum(m) * image.shape[-1])


def evaluate(glctx, tex, views: Views, resolution: int, *, mip: bool, chunk: int = 8) -> float:
    """PSNR (dB) of ``tex`` rendered with its filter against the views' targets, over their
    masks."""
    images = [render_texture(glctx, views.mvp[k:k + chunk], tex, resolution, mip=mip)[0]
              for k in range(0, views.mvp.shape[0], chunk)]
    return psnr(jnp.concatenate(images), views.target, views.mask)


def fit_texture(glctx, seed: int, *, mip: bool, resolution: int = 128,
                texture_size: int = 256, iterations: int = 1000, views: int = 4,
                pool: int = 64, eval_views: int = 8, eval_every: int = 50,
                lr: float = 1e-2, lr_decay: float = 0.1, supersample: int = 4,
                data: tuple | None = None, progress=None) -> TextureFit:
    """Fit the texture (see the module doc). ``data``: (pool Views, held-out Views) from
    :func:`make_data` to share between runs. ``progress``: optional callable
    ``(i, total, label)`` called every iteration. Timing sections: "forward+backward" (the
    loss and its gradient, one jitted call), "step" (Adam and the clamp)."""
    truth = jnp.asarray(procedural_texture(texture_size)[None], jnp.float32)
    if data is None:
        data = make_data(glctx, seed, resolution=resolution, texture_size=texture_size,
                         pool=pool, eval_views=eval_views, supersample=supersample)
    train, held_out = data
    rng = np.random.default_rng([seed, 1])
    tex = jnp.full_like(truth, 0.5)
    optimizer = adam(lr, lr_decay, iterations)
    state = optimizer.init(tex)
    mesh = _mesh()

    def loss_of(t, mvp, target, mask):
        image, _ = render_texture(glctx, mvp, t, resolution, mip=mip, mesh=mesh)
        return masked_mse(image, target, mask)

    loss_and_grad = jax.jit(jax.value_and_grad(loss_of))

    @jax.jit
    def step(t, state, grad):
        updates, state = optimizer.update(grad, state, t)
        return jnp.clip(optax.apply_updates(t, updates), 0.0, 1.0), state

    timer = Timer()
    eval_its, eval_psnr, tex_psnr, losses = [], [], [], []

    def measure(it):
        eval_its.append(it)
        eval_psnr.append(evaluate(glctx, tex, held_out, resolution, mip=mip))
        tex_psnr.append(psnr(np.clip(np.asarray(tex), 0, 1), truth))

    name = "mip" if mip else "linear"
    for it in range(iterations):
        if it % eval_every == 0:
            measure(it)
        pick = rng.choice(train.mvp.shape[0], views, replace=False)
        with timer("forward+backward"):
            loss, grad = jax.block_until_ready(loss_and_grad(
                tex, train.mvp[pick], train.target[pick], train.mask[pick]))
        with timer("step"):
            tex, state = jax.block_until_ready(step(tex, state, grad))
        losses.append(float(loss))
        if progress is not None:
            progress(it + 1, iterations, f"{name} seed {seed} PSNR {eval_psnr[-1]:.2f} dB")
    measure(iterations)
    return TextureFit(seed=seed, mip=mip, resolution=resolution, iterations=iterations,
                      views=views, texture_size=texture_size,
                      eval_iterations=np.array(eval_its), eval_psnr=np.array(eval_psnr),
                      texture_psnr=np.array(tex_psnr), loss=np.array(losses),
                      final=np.asarray(tex[0], np.float64), timing=timer.summary())


def make_data(glctx, seed: int, *, resolution: int = 128, texture_size: int = 256,
              pool: int = 64, eval_views: int = 8, supersample: int = 4):
    """(training pool, held-out views) of ``seed`` for :func:`fit_texture`."""
    truth = jnp.asarray(procedural_texture(texture_size)[None], jnp.float32)
    rng = np.random.default_rng([seed, 0])
    train = make_views(glctx, rng, pool, resolution, truth, supersample=supersample)
    held_out = make_views(glctx, rng, eval_views, resolution, truth, supersample=supersample)
    return train, held_out
