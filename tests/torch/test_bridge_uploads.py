"""Skipped uploads through glraster.torch: a tensor (of 1 KiB or more, ``KEYED_BYTES``)
unchanged since a buffer received it is not written again (``Context.uploads`` counts the
skips), and one changed in place (its version counter bumped), or a new tensor in the
same memory, is uploaded again, so the result is that of a context that never saw it
before."""

from __future__ import annotations

import gc

import numpy as np
import torch

import glraster.torch as dr
from glraster.geometry.shapes import box
from glraster.gpu.context import Context


def _scene(copies: int = 10):
    """``copies`` boxes, each a little smaller (tri, pos and colors above KEYED_BYTES)."""
    vertices, triangles = box()
    v = torch.tensor(vertices, dtype=torch.float32)
    v = torch.cat([v * (0.8 - 0.03 * k) for k in range(copies)])
    tri = torch.tensor(np.concatenate([triangles + len(vertices) * k for k in range(copies)]),
                       dtype=torch.int32)
    pos = torch.cat([v, torch.full((len(v), 1), 2.0)], 1)
    pos[:, 2] = 0.1 * pos[:, 0]
    colors = torch.rand(len(v), 4, generator=torch.Generator().manual_seed(1))
    assert min(t.nbytes for t in (tri, pos, colors)) >= dr.bridge.KEYED_BYTES
    return pos, tri, colors


def _render(glctx, pos, tri, colors, size=8):
    """Forward and backward through rasterize -> interpolate -> antialias: the image and
    the gradients of pos and colors (copies)."""
    pos = pos.detach().requires_grad_()
    colors.requires_grad_()
    rast, _ = dr.rasterize(glctx, pos, tri, (size, size))
    out, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    image = dr.antialias(out, rast, pos, tri, glctx=glctx)
    (image * torch.linspace(0.5, 1.5, image.numel()).reshape(image.shape)).sum().backward()
    grads = pos.grad.clone(), colors.grad.clone()
    colors.grad = None
    colors.requires_grad_(False)
    return image.detach().clone(), *grads


def _fresh(pos, tri, colors):
    """The same render on a context of its own (nothing cached)."""
    own = Context()
    try:
        return _render(dr.RasterizeGLContext(context=own), pos.clone(), tri.clone(),
                       colors.clone())
    finally:
        own.release()


def _same(got, want):
    for g, w in zip(got, want):
        np.testing.assert_allclose(g.numpy(), w.numpy(), rtol=1e-5, atol=1e-6)


def test_unchanged_tensors_are_not_uploaded_again(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    pos, tri, colors = _scene()
    first = _render(glctx, pos, tri, colors)
    uploads = ctx.uploads
    skipped, written = uploads.skipped, uploads.written
    again = _render(glctx, pos, tri, colors)
    # tri (rasterize, interpolate, antialias, each backward), colors, rast and pos: a second
    # call on the same tensors finds them in the buffers of the first one
    assert uploads.skipped - skipped >= 8
    assert again[0].equal(first[0])
    _same(again, _fresh(pos, tri, colors))
    # within one call each tensor is written at most once per buffer that reads it
    assert uploads.written - written <= 12


def test_an_in_place_change_is_uploaded_again(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    pos, tri, colors = _scene()
    _render(glctx, pos, tri, colors)
    version = colors._version
    with torch.no_grad():
        colors.mul_(0.5).add_(0.25)                      # the same tensor, new values
    tri[[0, 1]] = tri[[1, 0]].clone()                  # two triangles swap places
    assert colors._version > version
    _same(_render(glctx, pos, tri, colors), _fresh(pos, tri, colors))


def test_a_new_tensor_in_reused_memory_is_uploaded_again(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    pos, tri, colors = _scene()
    memory = colors.numpy().copy()
    first = torch.from_numpy(memory)
    _render(glctx, pos, tri, first)
    del first
    gc.collect()
    memory[:] = memory[::-1]                           # other values at the same address
    second = torch.from_numpy(memory)                  # version 0 again, same address
    _same(_render(glctx, pos, tri, second), _fresh(pos, tri, second))


def test_scratch_buffers_and_undeclared_data_are_always_written(ctx):
    """What a shader may write, and data nobody declared (JAX, arrays a core computes, a
    tensor under KEYED_BYTES), never matches a key."""
    assert dr.bridge.upload_entry(torch.zeros(255)) is None
    data = np.arange(512, dtype=np.float32)
    owner = torch.from_numpy(data)
    entry = dr.bridge.upload_entry(owner)
    with ctx, ctx.uploads.declared([entry]):
        ctx.storage_buffer("test.a", data)
        assert ctx.storage_buffer("test.b", data) is ctx.storage_buffer("test.a", data)
        skipped = ctx.uploads.skipped
        ctx.scratch_buffer("test.a", 2048)              # a shader may write it now
        ctx.scratch_buffer("test.b", 2048)
        ctx.storage_buffer("test.a", data)
        assert ctx.uploads.skipped == skipped
    skipped = ctx.uploads.skipped
    ctx.storage_buffer("test.a", data)                  # no declaration: written
    assert ctx.uploads.skipped == skipped
    with ctx:
        np.testing.assert_array_equal(
            np.frombuffer(ctx.storage_buffer("test.a", data).read(size=2048), np.float32), data)


def _interpolate_rast_writes(ctx, glctx, pos, tri, colors, change=None):
    """Rasterize then interpolate (no grad), ``change(rast)`` in between: the output
    and the name of the buffer that held rast for interpolate."""
    with torch.no_grad():
        rast, _ = dr.rasterize(glctx, pos, tri, (16, 16))
        if change is not None:
            change(rast)
        out, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    return out, ctx.uploads._where.get(dr.bridge.upload_entry(rast)[1])


def test_a_raster_stays_in_the_buffer_it_was_resolved_in(ctx):
    """rast read back whole from the resolve pass's buffer is not uploaded for the next
    op (that buffer holds its bytes), and the result is that of an upload; changed in
    place, it is uploaded again."""
    glctx = dr.RasterizeGLContext(context=ctx, output_db=False)
    pos, tri, colors = _scene()
    batch = torch.stack([pos, pos * torch.tensor([1.0, 0.9, 1.0, 1.0])])
    out, holder = _interpolate_rast_writes(ctx, glctx, batch, tri, colors)
    assert holder == "rasterize.rast"
    want = _fresh_interpolate(batch, tri, colors)
    assert out.equal(want)

    def flip(rast):
        rast[:] = rast.flip(1)                           # in place: a new version
    out, holder = _interpolate_rast_writes(ctx, glctx, batch, tri, colors, flip)
    assert holder == "interpolate.rast"                 # (uploaded)
    own = Context()
    try:
        other = dr.RasterizeGLContext(context=own, output_db=False)
        with torch.no_grad():
            rast, _ = dr.rasterize(other, batch, tri, (16, 16))
            want, _ = dr.interpolate(colors, rast.flip(1).contiguous(), tri, glctx=other)
    finally:
        own.release()
    assert out.equal(want)


def _fresh_interpolate(pos, tri, colors):
    """Rasterize -> interpolate on a context of its own, rast a copy (uploaded)."""
    own = Context()
    try:
        glctx = dr.RasterizeGLContext(context=own, output_db=False)
        with torch.no_grad():
            rast, _ = dr.rasterize(glctx, pos, tri, (16, 16))
            out, _ = dr.interpolate(colors, rast.clone(), tri, glctx=glctx)
        return out
    finally:
        own.release()


def _backward_uploads(ctx, monkeypatch, hook=None):
    """Rasterize -> interpolate, forward and backward (``hook`` on rast's gradient): pos'
    gradient and, per buffer rasterize's backward asked for, whether it was written."""
    glctx = dr.RasterizeGLContext(context=ctx, output_db=False)
    pos, tri, colors = _scene()
    pos = torch.stack([pos, pos * torch.tensor([1.0, 0.9, 1.0, 1.0])]).requires_grad_()
    asked, storage_buffer = {}, ctx.storage_buffer

    def logged(name, data):
        skipped = ctx.uploads.skipped
        buffer = storage_buffer(name, data)
        asked[name] = ctx.uploads.skipped == skipped
        return buffer
    monkeypatch.setattr(ctx, "storage_buffer", logged)
    rast, _ = dr.rasterize(glctx, pos, tri, (16, 16))
    if hook is not None:
        rast.register_hook(hook)
    out, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    (out * torch.linspace(0.5, 1.5, out.numel()).reshape(out.shape)).sum().backward()
    return pos.grad, {k: v for k, v in asked.items() if k.startswith("backward.")}


def test_the_rasterize_backward_binds_rast_and_its_gradient_where_they_are(ctx, monkeypatch):
    """rasterize's backward binds the buffers that hold rast (the resolve pass's) and
    grad_rast (interpolate's backward's, read back whole) instead of uploading them; a
    gradient that is another tensor (a hook's copy) is uploaded, to the same result."""
    grad, written = _backward_uploads(ctx, monkeypatch)
    assert not written["backward.rast"] and not written["backward.grad_rast"]
    want, written = _backward_uploads(ctx, monkeypatch, hook=lambda g: g.clone())
    assert written["backward.grad_rast"] and not written["backward.rast"]
    np.testing.assert_allclose(grad.numpy(), want.numpy(), rtol=1e-6, atol=1e-7)
    own = Context()
    try:
        fresh, _ = _backward_uploads(own, monkeypatch, hook=lambda g: g.clone())
    finally:
        own.release()
    np.testing.assert_allclose(grad.numpy(), fresh.numpy(), rtol=1e-6, atol=1e-7)
