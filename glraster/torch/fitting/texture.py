"""Recover a procedural texture on a sphere from images, with and without mipmaps.

Scene: a UV sphere of radius 1 (longitude u, latitude v, the seam column duplicated so
that u runs from 0 to 1) carrying a ``2N x N`` texture (:func:`procedural_texture`:
hue bands, a checkerboard, thin grid lines, so there is detail at every scale). Views turn
the sphere by a uniformly random rotation and put it at a distance drawn uniformly from
``distances`` in front of a 40 degree camera: from about one texel per pixel at the
equator of the nearest views down to several texels per pixel (levels ~0 to ~3).

Targets are the true texture rendered at ``supersample`` times the resolution along each
axis (linear-mipmap-linear, so even the sub-samples do not alias) and box-filtered down:
what a camera would see. A pool of ``pool`` such views is made once; every iteration
takes ``views`` of them at random, renders the texture being fitted through rasterize ->
interpolate (uv, and uv_da from ``diff_attrs``) -> texture and takes an Adam step on the
mean squared difference over the pixels that the sphere covers completely (all
sub-samples: the silhouette's partly covered pixels are left out of loss and PSNR, as
the fitted render is not antialiased). The texture starts grey (0.5).

``mip=True`` looks the texture up with ``filter_mode="linear-mipmap-linear"`` and the
derivatives ``uv_da``; ``mip=False`` with ``"linear"`` (bilinear in the base level only).
Quality is the PSNR over held-out views (a fixed set of ``eval_views``, each fit
rendering with its own filter) and the PSNR of the texture itself against the truth.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import torch

from glraster.fitting.results import TextureFit
from glraster.fitting.scenes import procedural_texture, uv_sphere
from glraster.torch.fitting.common import (
    Timer,
    clip_positions,
    descend,
    psnr,
    quaternion_matrices,
    random_quaternions,
    view_matrices,
)
from glraster.torch.ops import interpolate, rasterize
from glraster.torch.texture import texture

__all__ = ["TextureFit", "Views", "fit_texture", "make_views", "procedural_texture",
           "render_texture", "uv_sphere"]

FOVY = 40.0


@dataclass
class Views:
    """A set of views and their target images (torch tensors)."""

    mvp: torch.Tensor       # (N, 4, 4)
    target: torch.Tensor    # (N, H, W, 3)
    mask: torch.Tensor      # (N, H, W) bool: pixels the sphere covers completely
    distance: np.ndarray    # (N,)


def _mesh():
    verts, faces, uv = uv_sphere()
    return (torch.tensor(verts, dtype=torch.float32), torch.tensor(faces, dtype=torch.int32),
            torch.tensor(uv, dtype=torch.float32))


def render_texture(glctx, mvp, tex, resolution: int, *, mip: bool, mesh=None):
    """(N, R, R, C) images of ``tex`` (1, Ht, Wt, C) on the sphere under the (N, 4, 4)
    ``mvp`` and the (N, R, R) coverage; mip: linear-mipmap-linear with uv_da, else linear.
    Differentiable in ``tex``."""
    verts, tri, uv = mesh or _mesh()
    clip = clip_positions(mvp, verts)
    rast, rast_db = rasterize(glctx, clip, tri, (resolution, resolution), grad_db=mip)
    covered = rast[..., 3] > 0
    if mip:
        uv_img, uv_da = interpolate(uv[None], rast, tri, rast_db=rast_db, diff_attrs="all",
                                    glctx=glctx)
        out = texture(tex, uv_img, uv_da, filter_mode="linear-mipmap-linear", glctx=glctx)
    else:
        uv_img, _ = interpolate(uv[None], rast, tri, glctx=glctx)
        out = texture(tex, uv_img, filter_mode="linear", glctx=glctx)
    return out * covered[..., None], covered


def make_views(glctx, rng, n: int, resolution: int, tex, *, supersample: int = 4,
               distances=(3.0, 10.0), chunk: int = 4) -> Views:
    """``n`` random views and their supersampled targets of the true ``tex`` (1, Ht, Wt, 3)."""
    mesh = _mesh()
    rotations = quaternion_matrices(random_quaternions(rng, n))
    distance = rng.uniform(*distances, n)
    mvp = torch.tensor(view_matrices(rotations, distance=distance, fovy=FOVY),
                       dtype=torch.float32)
    targets, masks = [], []
    big = resolution * supersample
    with torch.no_grad():
        for k in range(0, n, chunk):
            image, covered = render_texture(glctx, mvp[k:k + chunk], tex, big, mip=True,
                                            mesh=mesh)
            b = image.shape[0]
            pooled = image.reshape(b, resolution, supersample, resolution, supersample, -1)
            targets.append(pooled.mean(dim=(2, 4)))
            cov = covered.reshape(b, resolution, supersample, resolution, supersample)
            masks.append(cov.all(dim=4).all(dim=2))
    return Views(mvp=mvp, target=torch.cat(targets), mask=torch.cat(masks), distance=distance)


class _MaskedSquares(torch.autograd.Function):
    """The loss of :func:`masked_mse` with the values and gradients of autograd's
    ``torch.sum(m * (image - target) ** 2) / (torch.sum(m) * C)`` bit for bit, its backward
    one pass over the pixels instead of autograd's four (mul, pow's ``d.pow(1)``, its
    doubling and product), and the forward's squares in a buffer of this thread's kept
    from call to call (as :func:`glraster.torch.fitting.common.mean_squares`)."""

    _squares = threading.local()

    @staticmethod
    def forward(fctx, image, target, mask):
        m = mask[..., None].to(image.dtype)
        d = image - target
        squares = getattr(_MaskedSquares._squares, "buffer", None)
        if squares is None or squares.shape != d.shape or squares.dtype != d.dtype:
            squares = _MaskedSquares._squares.buffer = torch.empty_like(d)
        torch.mul(m, torch.pow(d, 2, out=squares), out=squares)   # m * d ** 2, in place
        denominator = torch.sum(m) * image.shape[-1]
        fctx.save_for_backward(d, m, denominator)
        fctx.shapes = image.shape, target.shape
        return torch.sum(squares) / denominator

    @staticmethod
    def backward(fctx, g):
        d, m, denominator = fctx.saved_tensors
        image_shape, target_shape = fctx.shapes
        # autograd forms ((g / den) * m) * (2 d) (div's, mul's, then pow's backward); with
        # the doubling moved onto the (B, H, W, 1) factor, d * (2 ((g / den) * m)) rounds
        # the same exact product once: the same bits, signed zeros included (while 2 d
        # stays finite, as for images)
        grad = d * (2.0 * ((g / denominator) * m))
        return (grad.sum_to_size(image_shape) if fctx.needs_input_grad[0] else None,
                -grad.sum_to_size(target_shape) if fctx.needs_input_grad[1] else None, None)


def masked_mse(image, target, mask):
    """The mean of ``(image - target) ** 2`` over the (B, H, W, C) values whose pixel
    ``mask`` (B, H, W) is true: ``torch.sum(m * (image - target) ** 2) / (torch.sum(m) * C)``
    with m the mask as 0 / 1, the same value and gradients bit for bit."""
    return _MaskedSquares.apply(image, target, mask)


def evaluate(glctx, tex, views: Views, resolution: int, *, mip: bool, chunk: int = 8) -> float:
    """PSNR (dB) of ``tex`` rendered with its filter against the views' targets, over their
    masks."""
    images = []
    with torch.no_grad():
        for k in range(0, views.mvp.shape[0], chunk):
            images.append(render_texture(glctx, views.mvp[k:k + chunk], tex, resolution,
                                         mip=mip)[0])
    return psnr(torch.cat(images), views.target, views.mask)


def fit_texture(glctx, seed: int, *, mip: bool, resolution: int = 128,
                texture_size: int = 256, iterations: int = 1000, views: int = 4,
                pool: int = 64, eval_views: int = 8, eval_every: int = 50,
                lr: float = 1e-2, lr_decay: float = 0.1, supersample: int = 4,
                data: tuple | None = None, progress=None) -> TextureFit:
    """Fit the texture (see the module doc). ``data``: (pool Views, held-out Views) from
    :func:`make_views` to share between runs (the same seed makes the same ones).
    ``progress``: optional callable ``(i, total, label)`` called every iteration."""
    truth = torch.tensor(procedural_texture(texture_size)[None], dtype=torch.float32)
    if data is None:
        data = make_data(glctx, seed, resolution=resolution, texture_size=texture_size,
                         pool=pool, eval_views=eval_views, supersample=supersample)
    train, held_out = data
    rng = np.random.default_rng([seed, 1])
    tex = torch.full_like(truth, 0.5).requires_grad_(True)
    opt = torch.optim.Adam([tex], lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda it: lr_decay ** (it / max(iterations, 1)))
    mesh = _mesh()
    timer = Timer()
    eval_its, eval_psnr, tex_psnr, losses = [], [], [], []

    def measure(it):
        eval_its.append(it)
        eval_psnr.append(evaluate(glctx, tex.detach(), held_out, resolution, mip=mip))
        tex_psnr.append(psnr(tex.detach().clamp(0, 1), truth))

    name = "mip" if mip else "linear"
    for it in range(iterations):
        if it % eval_every == 0:
            measure(it)
        pick = torch.tensor(rng.choice(train.mvp.shape[0], views, replace=False))
        with timer("forward"):
            image, _ = render_texture(glctx, train.mvp[pick], tex, resolution, mip=mip,
                                      mesh=mesh)
            loss = masked_mse(image, train.target[pick], train.mask[pick])
        descend(timer, loss, opt, schedule, project=lambda: tex.clamp_(0.0, 1.0))
        losses.append(float(loss.detach()))
        if progress is not None:
            progress(it + 1, iterations, f"{name} seed {seed} PSNR {eval_psnr[-1]:.2f} dB")
    measure(iterations)
    return TextureFit(seed=seed, mip=mip, resolution=resolution, iterations=iterations,
                      views=views, texture_size=texture_size,
                      eval_iterations=np.array(eval_its), eval_psnr=np.array(eval_psnr),
                      texture_psnr=np.array(tex_psnr), loss=np.array(losses),
                      final=tex.detach()[0].double().numpy(), timing=timer.summary())


def make_data(glctx, seed: int, *, resolution: int = 128, texture_size: int = 256,
              pool: int = 64, eval_views: int = 8, supersample: int = 4):
    """(training pool, held-out views) of ``seed`` for :func:`fit_texture`."""
    truth = torch.tensor(procedural_texture(texture_size)[None], dtype=torch.float32)
    rng = np.random.default_rng([seed, 0])
    train = make_views(glctx, rng, pool, resolution, truth, supersample=supersample)
    held_out = make_views(glctx, rng, eval_views, resolution, truth, supersample=supersample)
    return train, held_out
