"""A fitting loop through glraster.torch allocates no OpenGL object once it is warm: the
cores' buffers (``Context.storage_buffer`` / ``scratch_buffer``, named and grown by
doubling), programs and framebuffers are reused from iteration to iteration, and a
constant texture's mip pyramid is not rebuilt.

Counted by wrapping every creating call of the moderngl context (buffer, texture,
framebuffer, program, compute_shader, renderbuffer, vertex_array, sampler, ...) while the
loop runs; the first iterations (shaders compiled, buffers sized) are not counted.
"""

from __future__ import annotations

import importlib

import torch

import glraster.torch as dr
from glraster.geometry.shapes import box

CREATORS = ("buffer", "texture", "texture_array", "texture_cube", "depth_texture",
            "framebuffer", "renderbuffer", "depth_renderbuffer", "program",
            "compute_shader", "vertex_array", "sampler")


def counting(monkeypatch, mgl) -> dict:
    made = {}
    for name in CREATORS:
        real = getattr(mgl, name)

        def create(*args, _real=real, _name=name, **kwargs):
            made[_name] = made.get(_name, 0) + 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(mgl, name, create)
    return made


def test_a_warm_fitting_loop_allocates_no_gl_objects(ctx, monkeypatch):
    glctx = dr.RasterizeGLContext(context=ctx)
    vertices, triangles = box()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=torch.float32)  # (8, 3)
    pos = torch.cat([v * 0.8, torch.full((len(v), 1), 2.0)], 1)
    pos[:, 2] = 0.1 * pos[:, 0]
    pos = pos[None].repeat(2, 1, 1).requires_grad_()        # two instanced views
    colors = torch.rand(1, len(v), 3, requires_grad=True)
    tex = torch.rand(1, 16, 16, 3)                           # constant: its pyramid is kept
    topology = dr.antialias_construct_topology_hash(tri)
    opt = torch.optim.Adam([pos, colors], lr=1e-3)

    def iteration(size=16):
        rast, rast_db = dr.rasterize(glctx, pos, tri, (size, size))
        col, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
        uv, uv_da = dr.interpolate(colors[..., :2], rast, tri, rast_db, diff_attrs="all",
                                   glctx=glctx)
        shaded = col * dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear",
                                  glctx=glctx)
        loss = dr.antialias(shaded, rast, pos, tri, topology, glctx=glctx).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    for _ in range(3):
        iteration()
    texture_module = importlib.import_module("glraster.torch.texture")
    pyramids = {k: v[1] for k, v in texture_module._PYRAMIDS.items()}
    made = counting(monkeypatch, ctx.mgl)
    for _ in range(5):
        iteration()
    assert made == {}
    # the constant texture's pyramid is the same object: not rebuilt
    assert {k: v[1] for k, v in texture_module._PYRAMIDS.items()} == pyramids
    # the count sees the cores' allocations: a larger image needs new framebuffers and
    # larger buffers
    iteration(size=96)
    assert made.get("framebuffer", 0) >= 1 and made.get("buffer", 0) >= 1
