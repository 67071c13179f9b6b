"""What the three fits share: rotations and quaternions, cameras, timing, PSNR.

Quaternions are (w, x, y, z), unit length after :func:`normalized`; rotation matrices act
on column vectors (``p' = R p``). Views are model-view-projection matrices (4, 4) that put
an object at the origin ``distance`` in front of a perspective camera looking down -z.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from contextlib import contextmanager

import numpy as np
import torch

from glraster.geometry import camera

__all__ = ["Timer", "angle_degrees", "clip_positions", "normalized", "psnr",
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


def random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) float64 unit quaternions, uniform over the rotations (normalized 4-D
    Gaussians), with w >= 0."""
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q


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


def angle_degrees(q1, q2) -> np.ndarray:
    """The rotation angle between two rotations given as quaternions, degrees in [0, 180]
    (q and -q are the same rotation): 4 atan2(|a - b|, |a + b|) of the unit quaternions
    with b's sign matched to a, which stays accurate for small angles (2 arccos |a . b|
    loses half the digits there)."""
    a, b = normalized(np.asarray(q1, np.float64)), normalized(np.asarray(q2, np.float64))
    a, b = np.broadcast_arrays(a, b)
    b = b * np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return np.degrees(4.0 * np.arctan2(np.linalg.norm(a - b, axis=-1),
                                       np.linalg.norm(a + b, axis=-1)))


def view_matrices(rotations, *, distance: float, fovy: float, near: float = 0.5,
                  far: float = 20.0, offsets=None) -> np.ndarray:
    """(N, 4, 4) float64 ``proj @ translate(0, 0, -distance) @ rotate``: an object at the
    origin turned by each of the (N, 3, 3) ``rotations``, seen by a square perspective
    camera of vertical field of view ``fovy`` degrees. ``distance`` may be a scalar or (N,);
    ``offsets`` (N, 2) optional eye-space shifts in x and y."""
    rotations = np.asarray(rotations, np.float64)
    n = rotations.shape[0]
    proj = camera.perspective(fovy, 1.0, near, far)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = rotations
    m[:, 2, 3] = -np.broadcast_to(np.asarray(distance, np.float64), (n,))
    if offsets is not None:
        m[:, :2, 3] = offsets
    return proj @ m


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


class Timer:
    """Wall-clock time per named section per iteration::

        timer = Timer()
        with timer("forward"): ...
        timer.summary()  # {"forward": {"mean_ms": ..., "median_ms": ..., "n": ...}, ...}
    """

    def __init__(self):
        self.times = defaultdict(list)

    @contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times[name].append(time.perf_counter() - t0)

    def summary(self) -> dict:
        return {name: {"mean_ms": 1e3 * float(np.mean(t)),
                       "median_ms": 1e3 * float(np.median(t)), "n": len(t)}
                for name, t in self.times.items()}

    @staticmethod
    def merge(summaries) -> dict:
        """Mean of the per-run means and medians, weighted by their counts."""
        out = {}
        for name in {k for s in summaries for k in s}:
            rows = [s[name] for s in summaries if name in s]
            n = sum(r["n"] for r in rows)
            out[name] = {k: sum(r[k] * r["n"] for r in rows) / n
                         for k in ("mean_ms", "median_ms")}
            out[name]["n"] = n
        return out


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
