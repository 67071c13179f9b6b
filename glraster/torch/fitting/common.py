"""What the three fits share: rotations and quaternions, cameras, timing, PSNR.

Quaternions are (w, x, y, z), unit length after :func:`normalized`; rotation matrices act
on column vectors (``p' = R p``). Views are model-view-projection matrices (4, 4) that put
an object at the origin ``distance`` in front of a perspective camera looking down -z.
"""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager

import numpy as np
import torch

from glraster.diff import recycle
from glraster.fitting.scenes import Timer, angle_degrees, random_quaternions, view_matrices

__all__ = ["Timer", "angle_degrees", "clip_positions", "mean_squares", "normalized", "psnr",
           "quaternion_matrices", "random_quaternions", "session", "view_matrices"]


@contextmanager
def session(*, backend: str | None = None, threads: int | None = 1):
    """A :class:`glraster.torch.RasterizeGLContext` on a new OpenGL context of ``backend``,
    with ``threads`` torch CPU threads (None: unchanged) while it is in use; on leaving the
    context is released and the thread count restored. One thread is usually fastest for
    the fits: their tensors are small, and llvmpipe's threads need the cores (on 2 busy
    cores an Adam step on 100k floats took 16 ms with 2 threads, 0.3 ms with 1)."""
    from glraster.gpu.context import Context
    from glraster.torch.context import RasterizeGLContext

    before = torch.get_num_threads()
    ctx = Context(backend=backend)
    try:
        if threads is not None:
            torch.set_num_threads(threads)
        yield RasterizeGLContext(context=ctx)
    finally:
        torch.set_num_threads(before)
        ctx.release()


def normalized(q):
    """q / |q| along the last axis (NumPy or torch)."""
    if isinstance(q, torch.Tensor):
        return q / q.norm(dim=-1, keepdim=True)
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_matrices(q):
    """(..., 3, 3) rotation matrices of (..., 4) quaternions (normalized here first); NumPy
    in, NumPy out; torch in, torch out (differentiable)."""
    q = normalized(q)
    w, x, y, z = (q[..., k] for k in range(4))
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]
    if isinstance(q, torch.Tensor):
        return torch.stack(rows, -1).reshape(q.shape[:-1] + (3, 3))
    return np.stack(rows, -1).reshape(q.shape[:-1] + (3, 3))


def clip_positions(mvp, vertices):
    """(N, V, 4) clip-space positions of (V, 3) ``vertices`` under (N, 4, 4) ``mvp``, both
    torch tensors (differentiable in both); contiguous, for instanced rasterization."""
    homogeneous = torch.cat([vertices, torch.ones_like(vertices[:, :1])], dim=1)
    return torch.einsum("bij,vj->bvi", mvp, homogeneous).contiguous()


def psnr(a, b, mask=None, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of ``a`` against ``b`` (NumPy or torch), over the
    pixels where ``mask`` (broadcast against the arrays' leading axes) is true."""
    a = a.detach().numpy() if isinstance(a, torch.Tensor) else np.asarray(a)
    b = b.detach().numpy() if isinstance(b, torch.Tensor) else np.asarray(b)
    d2 = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    if mask is not None:
        mask = mask.numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
        d2 = d2[np.broadcast_to(mask, d2.shape[:mask.ndim])]
    mse = float(d2.mean())
    return math.inf if mse == 0.0 else 10.0 * math.log10(peak * peak / mse)


class _MeanSquares(torch.autograd.Function):
    """Per image, the mean of (image - target)^2 over its other axes, the operations of
    ``torch.mean((image - target) ** 2, dim=(1, ...))``, with a backward of one pass over
    the pixels instead of the four of autograd's mean, pow and sub backward. The squares,
    read by the mean only, go to a buffer of this thread's kept from call to call (a new
    image-sized array costs its page faults: 1 ms of 3 for the forward at 8 x 256²); the
    difference and the gradient, which autograd holds, to memory used again once free
    (:func:`glraster.diff.recycle.empty`), computed by the same torch kernels (``out=``)."""

    _squares = threading.local()

    @staticmethod
    def forward(fctx, image, target):
        d = torch.sub(image, target, out=_recycled(torch.broadcast_shapes(
            image.shape, target.shape), torch.result_type(image, target)))
        fctx.save_for_backward(d)
        fctx.shapes = image.shape, target.shape
        squares = getattr(_MeanSquares._squares, "buffer", None)
        if squares is None or squares.shape != d.shape or squares.dtype != d.dtype:
            squares = _MeanSquares._squares.buffer = torch.empty_like(d)
        return torch.mean(torch.pow(d, 2, out=squares), dim=tuple(range(1, d.ndim)))

    @staticmethod
    def backward(fctx, g):
        (d,), (image_shape, target_shape) = fctx.saved_tensors, fctx.shapes
        # autograd forms (g / N) * (2 d) (mean's backward, then pow's): 2 (g / N) and 2 d
        # are exact doublings of the same float32 values, so d * (2 (g / N)) rounds the
        # same exact product once: the same bits (while 2 d stays finite, as for images)
        scale = 2.0 * (g / (d.numel() // max(d.shape[0], 1)))
        grad = torch.mul(d, scale.reshape((-1,) + (1,) * (d.ndim - 1)),
                         out=_recycled(d.shape, torch.result_type(d, scale)))
        return (grad.sum_to_size(image_shape) if fctx.needs_input_grad[0] else None,
                -grad.sum_to_size(target_shape) if fctx.needs_input_grad[1] else None)


def _recycled(shape, dtype) -> torch.Tensor:
    """An empty tensor of ``shape``, float32 or float64 in memory of
    :func:`glraster.diff.recycle.empty` (used again once free: no page faults), else new."""
    if dtype not in (torch.float32, torch.float64):
        return torch.empty(shape, dtype=dtype)
    return torch.from_numpy(recycle.empty(tuple(shape), np.float32 if dtype == torch.float32
                                          else np.float64))


def mean_squares(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """(B,) the mean squared difference of each image of ``image`` (B, ...) from ``target``
    (broadcast against it): ``torch.mean((image - target) ** 2, dim=(1, ...))``, the same
    values and gradients bit for bit, the gradient formed in one pass over the pixels
    (3 ms less per backward of 8 x 256 x 256 x 3 on 2 busy cores)."""
    return _MeanSquares.apply(image, target)


def descend(timer: Timer, loss, optimizer, schedule, project=None) -> None:
    """One optimizer step on ``loss``: the backward timed as "backward", the step, the
    schedule and ``project`` (run without autograd: a renormalisation or clamp of the
    parameters) as "step"."""
    with timer("backward"):
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
    with timer("step"):
        optimizer.step()
        schedule.step()
        if project is not None:
            with torch.no_grad():
                project()
