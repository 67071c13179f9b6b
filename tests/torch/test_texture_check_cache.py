"""The texture check tests a constant texture and its mip pyramid for NaN / Inf once: an
unchanged tensor of at least 1 KiB (smaller ones are not keyed: glraster.torch.bridge) (same storage, same torch version) is not scanned again, a changed one
is, and a NaN written in place is still refused with the argument's name."""

from __future__ import annotations

import math

import pytest
import torch

import glraster.torch as dr
from glraster.errors import ArgumentError


def call(glctx, tex, mip):
    uv = torch.rand(1, 8, 8, 2, generator=torch.Generator().manual_seed(1))
    da = torch.full((1, 8, 8, 4), 0.05)
    return dr.texture(tex, uv, da, mip=mip, filter_mode="linear-mipmap-linear", glctx=glctx)


def test_an_unchanged_texture_and_pyramid_are_scanned_once(ctx, scans):
    glctx = dr.RasterizeGLContext(context=ctx)
    tex = torch.rand(1, 32, 32, 4, generator=torch.Generator().manual_seed(0))  # 16 KiB
    mip = dr.texture_construct_mip(tex, glctx=glctx)
    first = call(glctx, tex, mip)
    after_first, levels = scans.count("tex"), scans.count("mip[0]")
    second = call(glctx, tex, mip)
    assert levels == 1, scans                                     # the first call's
    assert scans.count("tex") == after_first and scans.count("mip[0]") == 1, scans
    assert scans.count("uv_da") == 2                              # new tensors every call
    assert torch.equal(first, second)
    with torch.no_grad():
        tex.mul_(0.5)                                             # bumps the version
    mip = dr.texture_construct_mip(tex, glctx=glctx)
    third = call(glctx, tex, mip)
    assert scans.count("tex") > after_first and scans.count("mip[0]") == 2, scans
    assert torch.allclose(third, 0.5 * first, rtol=1e-6, atol=1e-7)


def test_a_nan_written_in_place_is_still_refused(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    tex = torch.rand(1, 32, 32, 4, generator=torch.Generator().manual_seed(0))
    mip = dr.texture_construct_mip(tex, glctx=glctx)
    call(glctx, tex, mip)
    with torch.no_grad():
        tex[0, 3, 5, 1] = math.nan
    with pytest.raises(ArgumentError, match="tex"):
        call(glctx, tex, mip)
