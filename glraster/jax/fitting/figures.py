"""The fits' figures from glraster.jax: :mod:`glraster.fitting.figures` drawn by
:class:`JaxRenderer`."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

import glraster.jax as dr
from glraster.fitting import figures as shared
from glraster.fitting.scenes import cube
from glraster.jax.fitting.cube import render_cube
from glraster.jax.fitting.pose import render_pose
from glraster.jax.fitting.texture import make_data, render_texture

__all__ = ["JaxRenderer", "cube_figures", "pose_figures", "texture_figures"]


class JaxRenderer:
    """:class:`glraster.fitting.figures.Renderer` on glraster.jax (float32)."""

    def __init__(self, glctx):
        self.glctx = glctx
        self.tri = cube()[1].astype(np.int32)
        self.topology = dr.antialias_construct_topology_hash(self.tri)

    def cube(self, mvp, vertices, colors, size, *, antialias):
        f32 = lambda a: jnp.asarray(np.asarray(a), jnp.float32)  # noqa: E731
        return np.asarray(render_cube(self.glctx, f32(mvp), f32(vertices), f32(colors),
                                      self.tri, size, antialias=antialias,
                                      topology=self.topology))

    def pose(self, quaternions, size, *, antialias):
        return np.asarray(render_pose(self.glctx, np.asarray(quaternions), size,
                                      antialias=antialias, topology=self.topology))

    def texture(self, mvp, tex, size, *, mip):
        image, _ = render_texture(self.glctx, jnp.asarray(np.asarray(mvp), jnp.float32),
                                  jnp.asarray(np.asarray(tex)[None], jnp.float32), size,
                                  mip=mip)
        return np.asarray(image)


def cube_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.cube_figures` drawn with glraster.jax."""
    return shared.cube_figures(fits, JaxRenderer(glctx), out_dir)


def pose_figures(fits, glctx, out_dir) -> list[Path]:
    """:func:`glraster.fitting.figures.pose_figures` drawn with glraster.jax."""
    return shared.pose_figures(fits, JaxRenderer(glctx), out_dir)


def texture_figures(pairs, glctx, out_dir, data=None) -> list[Path]:
    """:func:`glraster.fitting.figures.texture_figures` drawn with glraster.jax; ``data``:
    the first seed's (pool, held-out) views (made again when None)."""
    if data is None:
        lin = pairs[0][0]
        data = make_data(glctx, lin.seed, resolution=lin.resolution,
                         texture_size=lin.texture_size)
    return shared.texture_figures(pairs, JaxRenderer(glctx), out_dir, data=data)
