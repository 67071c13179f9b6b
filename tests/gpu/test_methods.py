"""Every barycentric method of rasterize() against the float64 reference, within its
documented error model (glraster.gpu.methods.error_model), on both backends."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster import reference
from glraster.geometry import synthetic
from glraster.verify.compare import compare
from glraster.gpu.methods import METHODS, error_model

RES = (96, 128)


def _scenes():
    return {
        # independent triangles, w log-uniform in [0.2, 20]: perspective matters
        "soup": synthetic.random_soup(120, seed=3),
        # small and sliver triangles
        "small_soup": synthetic.random_soup(300, seed=4, size=0.03),
        # shared edges, w varying smoothly across the mesh
        "grid": synthetic.grid(9, 7, seed=5, w_range=(0.5, 4.0)),
    }


SCENES = _scenes()


@pytest.fixture(scope="module")
def references():
    return {name: reference.rasterize(pos, tri, RES) for name, (pos, tri) in SCENES.items()}


@pytest.mark.parametrize("scene", sorted(SCENES))
@pytest.mark.parametrize("method", sorted(METHODS))
def test_method_matches_reference_within_its_model(ctx, references, method, scene):
    """Coverage and ids come from the driver for every method: exact outside the edge band.
    Values: within glraster.gpu.methods.error_model (per-pixel bounds, see glraster/verify/tolerance.py)."""
    pos, tri = SCENES[scene]
    r = gr.rasterize(pos, tri, RES, ctx=ctx, method=method)
    rep = compare(r, references[scene], error_model(method, ctx))
    assert rep.ok(), f"{method} on {scene}:\n{rep.summary()}"
    assert r.info["method"] == method


@pytest.mark.parametrize("method", ["homogeneous", "homogeneous64"])
def test_compensated_methods_are_accurate_to_a_few_float32_ulps(ctx, references, method):
    """The compensated methods round about once: on these scenes the error stays below
    4 ulps of 1 (4.8e-7), where hw reaches ~1e-4 on the small triangles."""
    for scene, (pos, tri) in SCENES.items():
        r = gr.rasterize(pos, tri, RES, ctx=ctx, method=method, outputs=("persp", "screen", "tri_id"))
        rep = compare(r, references[scene], error_model(method, ctx))
        for name in ("persp", "screen"):
            assert rep.values[name].max <= 4 * 2.0**-23, (scene, name, rep.values[name])


def test_homogeneous64_matches_the_reference_to_float32_rounding(ctx, references):
    """Double-precision evaluation: the only error left is the final rounding to the
    float32 target, half an ulp (2^-25 for values in [0.25, 0.5), at most 2^-24 below 1)."""
    pos, tri = SCENES["soup"]
    r = gr.rasterize(pos, tri, RES, ctx=ctx, method="homogeneous64", outputs=("persp", "tri_id"))
    ref = references["soup"]
    both = r.mask & ref.mask & (r.tri_id == ref.tri_id)
    err = np.abs(r.persp[both].astype(np.float64) - ref.persp[both])
    assert err.max() <= 2.0**-24


@pytest.mark.parametrize("method", sorted(METHODS))
def test_unrequested_outputs_are_none(ctx, method):
    pos, tri = SCENES["soup"]
    r = gr.rasterize(pos, tri, (32, 32), ctx=ctx, method=method, outputs=("screen",))
    assert r.persp is None and r.depth is None and r.tri_id is None
    # homogeneous64 returns its float64 values (read back exactly), every other method float32
    want = np.float64 if method == "homogeneous64" else np.float32
    assert r.screen.shape == (32, 32, 3) and r.screen.dtype == want
    r = gr.rasterize(pos, tri, (32, 32), ctx=ctx, method=method, outputs=("tri_id",))
    assert r.persp is None and r.screen is None and r.tri_id.dtype == np.int32


@pytest.mark.parametrize("method", sorted(METHODS))
def test_near_plane_crossing_gives_the_unclipped_formula(ctx, method):
    """A triangle with one vertex behind the eye (w < 0): values are those of the
    unclipped triangle (GL 4.5 section 13.7). Judged by each method's model. The methods
    that compute barycentrics themselves never output NaN or Inf; llvmpipe's clipper can
    put NaN into noperspective values here (hw, divw: the waiver in ErrorModel)."""
    pos = np.array([[-0.8, -0.6, 0.2, 1.0], [0.9, -0.5, 0.0, 2.0], [0.1, 0.8, -1.5, -0.5]],
                   np.float32)
    tri = np.array([[0, 1, 2]], np.int32)
    ref = reference.rasterize(pos, tri, (48, 48))
    r = gr.rasterize(pos, tri, (48, 48), ctx=ctx, method=method)
    rep = compare(r, ref, error_model(method, ctx))
    assert rep.covered_gpu > 0
    assert rep.ok(), rep.summary()
    if method == "divw" and ctx.is_llvmpipe:
        # divw divides the driver's noperspective values, which llvmpipe's clipper breaks
        # on triangles crossing two clip planes (docs/llvmpipe.md): counted as waived.
        assert rep.values["persp"].waived > 0
    names = ("persp", "depth") if method == "hw" else ("depth",) if method == "divw" else \
        ("persp", "screen", "depth")
    for name in names:
        assert np.isfinite(getattr(r, name)).all(), name


def test_affine_path_is_taken_when_every_w_is_equal(ctx):
    """w = 2 everywhere: persp equals screen, rendered once and copied."""
    pos, tri = synthetic.random_soup(150, seed=6, w_range=(2.0, 2.0))
    for method in METHODS:
        r = gr.rasterize(pos, tri, RES, ctx=ctx, method=method)
        assert r.info["affine"], method
        assert np.array_equal(r.persp, r.screen)
        assert r.persp is not r.screen  # separate arrays: writing one leaves the other
        ref = reference.rasterize(pos, tri, RES)
        rep = compare(r, ref, error_model(method, ctx))
        assert rep.ok(), f"{method}\n{rep.summary()}"


def test_affine_path_agrees_with_the_general_path(ctx):
    """Same scene with affine=False: identical coverage and ids, values within 2^-20 (hw
    persp through the perspective divide differs by rounding only)."""
    pos, tri = synthetic.grid(12, 10, seed=7)
    fast = gr.rasterize(pos, tri, RES, ctx=ctx)
    slow = gr.rasterize(pos, tri, RES, ctx=ctx, affine=False)
    assert fast.info["affine"] and not slow.info["affine"]
    assert np.array_equal(fast.tri_id, slow.tri_id)
    assert np.array_equal(fast.depth, slow.depth)
    assert np.abs(fast.persp - slow.persp).max() <= 2.0**-20


def test_mixed_w_disables_the_affine_path(ctx):
    pos, tri = synthetic.random_soup(20, seed=8)
    assert not gr.rasterize(pos, tri, (16, 16), ctx=ctx).info["affine"]


def test_invalid_method_arguments_name_the_argument():
    pos, tri = synthetic.random_soup(2, seed=9)
    with pytest.raises(ValueError, match="method must be one of"):
        gr.rasterize(pos, tri, (8, 8), method="exact")
    with pytest.raises(ValueError, match="shader_files"):
        gr.rasterize(pos, tri, (8, 8), method="divw", shader_files=("a.vert", "b.frag"))
    with pytest.raises(ValueError, match="affine must be"):
        gr.rasterize(pos, tri, (8, 8), affine=True)
    with pytest.raises(ValueError, match="method must be one of"):
        error_model("exact")


@pytest.mark.parametrize("method", sorted(METHODS))
def test_batched_draws_give_the_same_image(gl_backend, method):
    """With a storage block limit small enough to split the draw (index, setup and id
    arrays per batch), every output equals the single-draw image: ids stay global."""
    pos, tri = synthetic.grid(8, 6, seed=12, w_range=(0.5, 3.0))   # 63 vertices, 96 triangles
    ctx = gr.Context(gl_backend)   # its own: the test lowers its storage block limit
    try:
        whole = gr.rasterize(pos, tri, (40, 56), ctx=ctx, method=method, cull=False)
        ctx.max_storage_block_size = 1024   # 1008-byte pos fits; 85 triangles per index batch
        split = gr.rasterize(pos, tri, (40, 56), ctx=ctx, method=method, cull=False)
        for name in ("persp", "screen", "depth", "tri_id"):
            assert np.array_equal(getattr(whole, name), getattr(split, name)), name
        assert ctx.gl_error() == "GL_NO_ERROR"
    finally:
        ctx.release()
