"""Recover a cube's rotation from one image of it.

The cube and colours of :mod:`glraster.torch.fitting.cube` (each vertex its own colour, so
every rotation gives a different image), seen by one fixed camera. The true rotation is a
uniformly random quaternion (seeded). The parameters are ``restarts`` quaternions, also
uniformly random, fitted side by side (one instanced draw of all of them per iteration)
by Adam on the sum of their mean squared image differences through rasterize ->
interpolate -> antialias; each is normalized before use, so the loss depends on its
direction only. The learning rate falls exponentially from ``lr`` to ``lr * lr_decay``.
The answer is the restart with the lowest final image loss; its error is the angle of the
rotation between it and the truth.

Gradient descent alone mostly stops in a wrong minimum: a cube turned by one of its 24
symmetries has the same silhouette, so a fit whose outline matches but whose colours are
permuted sits in a local minimum 90, 120 or 180 degrees away. With ``jumps`` (the
default: after 1/4 and 1/2 of the iterations), every restart is compared with its 23
symmetric variants ``q * s`` (s one of the cube's rotations, applied in the object frame;
forward only, one draw of all of them) and continues from the one with the lowest loss.
The optimizer keeps its moments (fresh ones would kick every restart, the converged ones
too, by about the learning rate in the first step; the stale first moment of a restart
that jumped fades within ~10 steps). This is a deterministic form of the random jumps by
cube symmetries in nvdiffrast's pose sample.
"""

from __future__ import annotations

import numpy as np
import torch

from glraster.fitting.results import PoseFit
from glraster.fitting.scenes import cube, cube_symmetries, pose_camera
from glraster.torch.fitting.common import (
    Timer,
    angle_degrees,
    descend,
    mean_squares,
    normalized,
    quaternion_matrices,
    random_quaternions,
)
from glraster.torch.fitting.render import shade, topology_hash

__all__ = ["PoseFit", "cube_symmetries", "fit_pose", "multiply", "render_pose"]


def multiply(a, b):
    """Hamilton product of quaternions (..., 4) (NumPy or torch): R(a b) = R(a) R(b)."""
    aw, ax, ay, az = (a[..., k] for k in range(4))
    bw, bx, by, bz = (b[..., k] for k in range(4))
    parts = [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
             aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw]
    return torch.stack(parts, -1) if isinstance(a, torch.Tensor) else np.stack(parts, -1)


def _camera() -> torch.Tensor:
    """(4, 4) float32: proj @ translate(0, 0, -DISTANCE)."""
    return torch.tensor(pose_camera(), dtype=torch.float32)


def render_pose(glctx, q, resolution: int, *, antialias=True, topology=None):
    """(N, R, R, 3) images of the cube turned by each of the (N, 4) quaternions ``q``
    (torch, differentiable)."""
    vertices, triangles, colors = cube()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=torch.float32)
    rotated = torch.einsum("nij,vj->nvi", quaternion_matrices(q.float()), v)
    clip = torch.cat([rotated, torch.ones_like(rotated[..., :1])], -1) @ _camera().T
    image, _ = shade(glctx, clip.contiguous(), tri, torch.tensor(colors, dtype=torch.float32),
                     (resolution, resolution), antialias=antialias, topology=topology)
    return image


def fit_pose(glctx, seed: int, *, resolution: int = 32, restarts: int = 8,
             iterations: int = 300, lr: float = 3e-2, lr_decay: float = 0.03,
             jumps=(0.25, 0.5), antialias: bool = True, progress=None) -> PoseFit:
    """Recover the rotation of ``seed`` (see the module doc). ``jumps``: the fractions of
    the run after which every restart moves to its best symmetric variant (() for none).
    ``progress``: optional callable ``(i, total, label)`` called every iteration."""
    _, triangles, _ = cube()
    topology = topology_hash(torch.tensor(triangles, dtype=torch.int32)) if antialias else None
    rng = np.random.default_rng(seed)
    target_q = random_quaternions(rng, 1)[0]
    start = random_quaternions(rng, restarts)
    with torch.no_grad():
        target = render_pose(glctx, torch.tensor(target_q[None]), resolution,
                             antialias=antialias, topology=topology)
    q = torch.tensor(start, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([q], lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda it: lr_decay ** (it / max(iterations, 1)))
    timer = Timer()
    angles, losses, jumped = [], [], []
    jump_at = sorted({round(f * iterations) for f in jumps} - {0, iterations})
    symmetries = torch.tensor(cube_symmetries(), dtype=torch.float32)
    for it in range(iterations + 1):
        if it in jump_at:
            with timer("jump"), torch.no_grad():
                variants = multiply(q[:, None, :], symmetries[None, :, :]).reshape(-1, 4)
                image = render_pose(glctx, variants, resolution, antialias=antialias,
                                    topology=topology)
                err = torch.mean((image - target) ** 2, dim=(1, 2, 3)).reshape(restarts, -1)
                choice = torch.argmin(err, dim=1)
                q.copy_(variants.reshape(restarts, -1, 4)[torch.arange(restarts), choice])
            jumped.append((it, [int(c) for c in choice]))
        angles.append(angle_degrees(q.detach().double().numpy(), target_q))
        with timer("forward"):
            image = render_pose(glctx, q, resolution, antialias=antialias, topology=topology)
            per_restart = mean_squares(image, target)
            loss = per_restart.sum()
        if it == iterations:  # the loss at the final parameters: no step
            timer.times["forward"].pop()
            final_loss = per_restart.detach().double().numpy()
            break
        descend(timer, loss, opt, schedule, project=lambda: q.div_(q.norm(dim=1, keepdim=True)))
        losses.append(per_restart.detach().double().numpy())
        if progress is not None:
            best = int(np.argmin(losses[-1]))
            progress(it + 1, iterations, f"seed {seed} best restart {best} angle "
                                         f"{angles[-1][best]:.1f} deg")
    best = int(np.argmin(final_loss))
    return PoseFit(seed=seed, resolution=resolution, iterations=iterations, restarts=restarts,
                   antialias=antialias, target=target_q, start=start,
                   final=normalized(q.detach().double().numpy()), angle=np.array(angles),
                   loss=np.array(losses).reshape(iterations, restarts), best=best,
                   final_loss=final_loss, jumps=jumped, timing=timer.summary())
