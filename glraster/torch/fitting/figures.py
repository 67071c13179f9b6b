"""The fits' figures from glraster.torch: the curves and pictures of
:mod:`glraster.fitting.figures`, drawn by :class:`TorchRenderer`, and the texture fit's
(``fit-texture-psnr.png``, ``fit-texture-before-after.png``, ``fit-texture-views.png``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from glraster.fitting import figures as shared
from glraster.io import figures
from glraster.torch.fitting import cube as cube_mod
from glraster.torch.fitting import pose as pose_mod
from glraster.torch.fitting import texture as texture_mod

__all__ = ["GAP", "PANEL", "TorchRenderer", "cube_figures", "grid", "pose_figures",
           "texture_figures"]

GAP, PANEL, grid = shared.GAP, shared.PANEL, shared.grid


class TorchRenderer:
    """:class:`glraster.fitting.figures.Renderer` on glraster.torch (float32, no grad)."""

    def __init__(self, glctx):
        from glraster.torch.fitting.render import topology_hash

        self.glctx = glctx
        self.tri = torch.tensor(cube_mod.cube()[1], dtype=torch.int32)
        self.topology = topology_hash(self.tri)

    @torch.no_grad()
    def cube(self, mvp, vertices, colors, size, *, antialias):
        f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
        return cube_mod.render_cube(self.glctx, f32(mvp), f32(vertices), f32(colors), self.tri,
                                    size, antialias=antialias,
                                    topology=self.topology).numpy()

    @torch.no_grad()
    def pose(self, quaternions, size, *, antialias):
        return pose_mod.render_pose(self.glctx, torch.tensor(np.asarray(quaternions)), size,
                                    antialias=antialias, topology=self.topology).numpy()


def cube_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.cube_figures` drawn with glraster.torch."""
    return shared.cube_figures(fits, TorchRenderer(glctx), out_dir)


def pose_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.pose_figures` drawn with glraster.torch."""
    return shared.pose_figures(fits, TorchRenderer(glctx), out_dir)


def _upright(img) -> np.ndarray:
    a = img.detach().numpy() if isinstance(img, torch.Tensor) else np.asarray(img)
    return shared.upright(a)


# --------------------------------------------------------------------------- texture


def texture_figures(pairs, glctx, out_dir, data=None) -> list[Path]:
    """Write fit-texture-psnr.png, fit-texture-before-after.png and fit-texture-views.png
    for a list of (linear TextureFit, mipmapped TextureFit) pairs, one per seed; ``data``:
    the first seed's (pool, held-out) views (made again when None)."""
    out_dir = Path(out_dir)
    paths = []
    with figures.figure(out_dir / "fit-texture-psnr.png", figsize=(9.0, 3.6),
                        title="glraster fit texture: PSNR",
                        description="held-out image PSNR and texture PSNR, linear against "
                                    "linear-mipmap-linear") as fig:
        ax1, ax2 = fig.subplots(1, 2)
        col = figures.colors(["linear", "linear-mipmap-linear"])
        for lin, mip in pairs:
            for f, name, ls in ((lin, "linear", "--"), (mip, "linear-mipmap-linear", "-")):
                ax1.plot(f.eval_iterations, f.eval_psnr, color=col[name], ls=ls, lw=1.0,
                         label=f"{name}, seed {f.seed}: {f.eval_psnr[-1]:.2f} dB")
                ax2.plot(f.eval_iterations, f.texture_psnr, color=col[name], ls=ls, lw=1.0,
                         label=f"{name}, seed {f.seed}: {f.texture_psnr[-1]:.2f} dB")
        ax1.set_title(f"held-out views ({pairs[0][0].resolution}² px, covered pixels)")
        ax2.set_title(f"texture ({2 * pairs[0][0].texture_size} x {pairs[0][0].texture_size}) "
                      f"against the truth")
        for ax in (ax1, ax2):
            ax.set_xlabel("iteration")
            ax.set_ylabel("PSNR (dB)")
            ax.grid(True)
            ax.legend(loc="lower right", fontsize=7)
    paths.append(out_dir / "fit-texture-psnr.png")

    lin, mip = pairs[0]
    truth = texture_mod.procedural_texture(lin.texture_size)
    paths.append(shared.write_grid(out_dir / "fit-texture-before-after.png",
                        [[_upright(truth)], [_upright(lin.final)], [_upright(mip.final)]],
                        "glraster fit texture: truth, linear fit, mipmapped fit"))
    if data is None:
        data = texture_mod.make_data(glctx, lin.seed, resolution=lin.resolution,
                                     texture_size=lin.texture_size)
    held_out = data[1]
    order = np.argsort(held_out.distance)
    rows = []
    for k in (order[0], order[-1]):
        mvp = held_out.mvp[k:k + 1]
        row = [shared.scaled(_upright(held_out.target[k]), 2 * lin.resolution)]
        with torch.no_grad():
            for f in (lin, mip):
                tex = torch.tensor(f.final[None], dtype=torch.float32)
                img, _ = texture_mod.render_texture(glctx, mvp, tex, f.resolution, mip=f.mip)
                row.append(shared.scaled(_upright(img[0]), 2 * lin.resolution))
        rows.append(row)
    paths.append(shared.write_grid(out_dir / "fit-texture-views.png", rows,
                        "glraster fit texture: target, linear fit, mipmapped fit"))
    return paths
