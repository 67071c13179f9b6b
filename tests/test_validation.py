"""Bad input gets a ValueError that names the argument; no GL error is left behind."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr

GOOD_POS = np.array([[0, 0, 0, 1], [1, 0, 0, 1], [0, 1, 0, 1]], np.float32)
GOOD_TRI = np.array([[0, 1, 2]])


@pytest.mark.parametrize(
    "pos, message",
    [
        (np.zeros((5, 3), np.float32), r"pos must have shape \(V, 4\), got \(5, 3\)"),
        (np.zeros(4, np.float32), r"pos must have shape \(V, 4\), got \(4,\)"),
        (np.array([["a", "b", "c", "d"]] * 3), "pos must hold real numbers"),
        (np.zeros((3, 4), np.complex64), "pos must hold real numbers"),
        (np.zeros((3, 4), bool), "pos must hold real numbers"),
        (np.array([[0, 0, 0, 1], [np.nan, 0, 0, 1], [0, 1, 0, 1]]), "row 1 has NaN or Inf"),
        (np.array([[0, 0, 0, 1], [1, 0, 0, 1], [0, np.inf, 0, 1]]), "row 2 has NaN or Inf"),
        (np.array([[0, 0, 0, 1], [1e39, 0, 0, 1], [0, 1, 0, 1]]), "beyond float32 range"),
    ],
)
def test_bad_positions(ctx, pos, message):
    with pytest.raises(ValueError, match=message):
        gr.rasterize(pos, [[0, 1, 2]], (8, 8), ctx=ctx)
    with pytest.raises(ValueError, match=message):
        gr.reference.rasterize(pos, [[0, 1, 2]], (8, 8))


@pytest.mark.parametrize(
    "tri, message",
    [
        (np.array([[0, 1]]), r"tri must have shape \(T, 3\), got \(1, 2\)"),
        (np.array([0, 1, 2]), r"tri must have shape \(T, 3\), got \(3,\)"),
        (np.array([[0.0, 1.0, 2.0]]), "tri must have an integer dtype, got float64"),
        (np.array([[0, -1, 2]]), "tri must hold indices >= 0, got -1"),
        (np.array([[0, 1, 3]]), "tri index 3 is out of range for pos with 3 vertices"),
    ],
)
def test_bad_triangles(ctx, tri, message):
    with pytest.raises(ValueError, match=message):
        gr.rasterize(GOOD_POS, tri, (8, 8), ctx=ctx)
    with pytest.raises(ValueError, match=message):
        gr.reference.rasterize(GOOD_POS, tri, (8, 8))


@pytest.mark.parametrize(
    "resolution, message",
    [
        ((0, 8), "resolution height must be > 0, got 0"),
        ((8, -2), "resolution width must be > 0, got -2"),
        ((8.0, 8), "resolution height must be an integer, got 8.0"),
        ((True, 8), "resolution height must be an integer"),
        (8, "resolution must be \\(height, width\\), got 8"),
        ((8, 8, 3), "resolution must be \\(height, width\\)"),
    ],
)
def test_bad_resolution(ctx, resolution, message):
    with pytest.raises(ValueError, match=message):
        gr.rasterize(GOOD_POS, GOOD_TRI, resolution, ctx=ctx)


def test_resolution_above_the_driver_limit(ctx):
    too_big = ctx.max_texture_size + 1
    with pytest.raises(ValueError, match=f"resolution width {too_big} exceeds the driver's maximum"):
        gr.rasterize(GOOD_POS, GOOD_TRI, (4, too_big), ctx=ctx)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"outputs": ("persp", "normals")}, r"outputs has unknown names \['normals'\]"),
        ({"outputs": ()}, "outputs must name at least one"),
        ({"outputs": 5}, "outputs must be a sequence"),
        ({"method": "magic"}, "method must be one of"),
    ],
)
def test_bad_options(ctx, kwargs, message):
    with pytest.raises(ValueError, match=message):
        gr.rasterize(GOOD_POS, GOOD_TRI, (8, 8), ctx=ctx, **kwargs)


def test_reference_options_are_checked():
    with pytest.raises(ValueError, match="fill_rule must be 'llvmpipe' or None"):
        gr.reference.rasterize(GOOD_POS, GOOD_TRI, (8, 8), fill_rule="topleft")
    with pytest.raises(ValueError, match="edge_band_px must be a finite number >= 0"):
        gr.reference.rasterize(GOOD_POS, GOOD_TRI, (8, 8), edge_band_px=-1)


def test_integer_and_float64_positions_are_converted_once(ctx):
    as_int = gr.rasterize(np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]]),
                          GOOD_TRI, (16, 16), ctx=ctx)
    as_f32 = gr.rasterize(np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]], np.float32),
                          GOOD_TRI, (16, 16), ctx=ctx)
    np.testing.assert_array_equal(as_int.persp, as_f32.persp)


def test_targets_the_driver_cannot_allocate_are_a_clear_error(ctx):
    # 16384 x 16384 is within GL_MAX_TEXTURE_SIZE, but a vec3 float32 target of that size
    # holds 3-4 GiB, more than llvmpipe allocates for one texture. The call must fail with
    # a ValueError naming the resolution, leave no GL error and no half-built framebuffer,
    # and the context must keep working.
    if not ctx.is_llvmpipe or ctx.max_texture_size < 16384:
        pytest.skip("the allocation limit measured here is llvmpipe's")
    gr.rasterize(GOOD_POS, GOOD_TRI, (16, 16), ctx=ctx, outputs=("screen",))  # the program
    before = ctx.cached_object_count()
    with pytest.raises(ValueError, match="resolution 16384x16384: the driver cannot allocate"):
        gr.rasterize(GOOD_POS, GOOD_TRI, (16384, 16384), ctx=ctx, outputs=("screen",))
    assert ctx.gl_error() == "GL_NO_ERROR"
    assert ctx.cached_object_count() == before
    assert gr.rasterize(GOOD_POS, GOOD_TRI, (16, 16), ctx=ctx).mask.any()
