"""The fits' figures from glraster.torch: the curves and pictures of
:mod:`glraster.fitting.figures`, drawn by :class:`TorchRenderer`, and the texture fit's
(``fit-texture-psnr.png``, ``fit-texture-before-after.png``, ``fit-texture-views.png``) and
the envmap fit's (``fit-envmap-error.png``, ``fit-envmap-before-after.png``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from glraster.fitting import figures as shared
from glraster.torch.fitting import cube as cube_mod
from glraster.torch.fitting import envmap as envmap_mod
from glraster.torch.fitting import pose as pose_mod
from glraster.torch.fitting import texture as texture_mod

__all__ = ["GAP", "PANEL", "TorchRenderer", "cube_figures", "envmap_figures", "grid",
           "pose_figures", "texture_figures"]

GAP, PANEL, grid = shared.GAP, shared.PANEL, shared.grid


class TorchRenderer:
    """:class:`glraster.fitting.figures.Renderer` on glraster.torch (float32, no grad)."""

    def __init__(self, glctx):
        from glraster.torch.fitting.render import topology_hash

        self.glctx = glctx
        self.tri = torch.tensor(cube_mod.cube()[1], dtype=torch.int32)
        self.topology = topology_hash(self.tri)
        self._envmap_scenes = {}

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

    @torch.no_grad()
    def texture(self, mvp, tex, size, *, mip):
        image, _ = texture_mod.render_texture(
            self.glctx, torch.tensor(np.asarray(mvp), dtype=torch.float32),
            torch.tensor(np.asarray(tex)[None], dtype=torch.float32), size, mip=mip)
        return image.numpy()

    @torch.no_grad()
    def envmap(self, quaternions, material, size, *, mesh, env_size, env=None):
        key = (tuple(mesh), env_size)
        if key not in self._envmap_scenes:
            self._envmap_scenes[key] = envmap_mod.make_scene(self.glctx, mesh=mesh,
                                                             env_size=env_size)
        mvp, eye = envmap_mod.view_setup(quaternions)
        f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
        image, _ = envmap_mod.render_envmap(
            self.glctx, self._envmap_scenes[key], mvp, eye, f32(material["diffuse"]),
            f32(material["specular"]), f32(material["exponent"]), size,
            env=None if env is None else f32(env)[None])
        return image.numpy()


def cube_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.cube_figures` drawn with glraster.torch."""
    return shared.cube_figures(fits, TorchRenderer(glctx), out_dir)


def pose_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.pose_figures` drawn with glraster.torch."""
    return shared.pose_figures(fits, TorchRenderer(glctx), out_dir)


def texture_figures(pairs, glctx, out_dir, data=None) -> list[Path]:
    """:func:`glraster.fitting.figures.texture_figures` drawn with glraster.torch; ``data``:
    the first seed's (pool, held-out) views (made again when None)."""
    if data is None:
        lin = pairs[0][0]
        data = texture_mod.make_data(glctx, lin.seed, resolution=lin.resolution,
                                     texture_size=lin.texture_size)
    return shared.texture_figures(pairs, TorchRenderer(glctx), out_dir, data=data)


def envmap_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.envmap_figures` drawn with glraster.torch."""
    return shared.envmap_figures(fits, TorchRenderer(glctx), out_dir)
