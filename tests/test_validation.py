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


# -- glraster.validate: every check raises ArgumentError naming its argument -----------------

from glraster import validate as V  # noqa: E402
from glraster.errors import ArgumentError  # noqa: E402

BAD_INPUTS = [
    # (check, the bad call, the argument it names, words of the message)
    ("real_array", lambda: V.real_array("uv", np.array(["a"])), "uv",
     "uv must hold real numbers (float or int), got dtype <U1"),
    ("real_array", lambda: V.real_array("uv", np.ones(3, bool)), "uv", "got dtype bool"),
    ("real_array", lambda: V.real_array("uv", np.ones(3, np.complex64)), "uv",
     "got dtype complex64"),
    ("finite", lambda: V.finite("tex", np.array([1.0, np.nan]), np.array([1.0, np.nan])),
     "tex", "tex must be finite, got NaN or Inf at index (1,)"),
    ("finite", lambda: V.finite("tex", np.array([[1e39]]), np.array([[np.inf]], np.float32)),
     "tex", "tex must be finite, got a value beyond float32 at index (0, 0)"),
    ("positions", lambda: V.positions(np.zeros((3, 3))), "pos",
     "pos must have shape (V, 4), got (3, 3)"),
    ("positions", lambda: V.positions(np.zeros((2, 3, 4))), "pos", "pos must have shape (V, 4)"),
    ("positions", lambda: V.positions([[0, 0, 0, np.inf]]), "pos", "row 0 has NaN or Inf"),
    ("positions", lambda: V.positions(np.zeros((3, 4), object)), "pos", "real numbers"),
    ("batched_positions", lambda: V.batched_positions(np.zeros((3, 3))), "pos",
     "pos must have shape (V, 4) or (B, V, 4), got (3, 3)"),
    ("batched_positions", lambda: V.batched_positions(np.zeros((0, 3, 4))), "pos",
     "pos must have a batch of at least 1"),
    ("batched_positions", lambda: V.batched_positions(np.full((1, 3, 4), 1e39), np.float32),
     "pos", "pos must be finite, got a value beyond float32 at index (0, 0, 0)"),
    ("triangles", lambda: V.triangles([[0, 1, 2.0]], 3), "tri", "tri must have an integer dtype"),
    ("triangles", lambda: V.triangles([[0, 1]], 3), "tri", "tri must have shape (T, 3)"),
    ("triangles", lambda: V.triangles([[0, -1, 2]], 3), "tri", "tri must hold indices >= 0"),
    ("triangles", lambda: V.triangles([[0, 1, 3]], 3), "tri",
     "tri index 3 is out of range for pos with 3 vertices"),
    ("triangles", lambda: V.triangles([[0, 1, 3]], 3, of="attr"), "tri",
     "tri index 3 is out of range for attr with 3 rows (vertices)"),
    ("ranges", lambda: V.ranges([[0, 1]], 2, pos_ndim=3), "ranges", "ranges needs pos of shape"),
    ("ranges", lambda: V.ranges([[0.0, 1.0]], 2, pos_ndim=2), "ranges",
     "ranges must have an integer dtype"),
    ("ranges", lambda: V.ranges(np.zeros((0, 2), int), 2, pos_ndim=2), "ranges",
     "ranges must have shape (B, 2) with B >= 1"),
    ("ranges", lambda: V.ranges([[0, -1]], 2, pos_ndim=2), "ranges",
     "ranges row 0 must have first >= 0 and count >= 0"),
    ("ranges", lambda: V.ranges([[0, 1], [1, 2]], 2, pos_ndim=2), "ranges",
     "ranges row 1 = [1, 2] reaches triangle 2, beyond tri's 2 triangles"),
    ("image", lambda: V.image("rast", np.zeros((4, 4, 4))), "rast",
     "rast must have shape (B, H, W, 4), got (4, 4, 4)"),
    ("image", lambda: V.image("dy", np.zeros((1, 4, 4, 2)), shape=(1, 4, 4, 3)), "dy",
     "dy must have shape (1, 4, 4, 3), got (1, 4, 4, 2)"),
    ("image", lambda: V.image("rast_db", np.full((1, 1, 1, 4), np.nan)), "rast_db",
     "rast_db must be finite, got NaN or Inf at index (0, 0, 0, 0)"),
    ("image", lambda: V.image("rast", np.zeros((1, 1, 1, 4), bool)), "rast", "real numbers"),
    ("image_shape", lambda: V.image_shape("rast", np.zeros((1, 4, 4, 3))), "rast",
     "rast must have shape (B, H, W, 4), got (1, 4, 4, 3)"),
    ("triangle_ids", lambda: V.triangle_ids("rast", np.array([-1, 0, 5]), 2), "rast",
     "rast holds triangle id 6 (index 5), beyond tri's 2 triangles"),
    ("attributes", lambda: V.attributes(np.zeros(3), 1), "attr",
     "attr must have shape (V, A) or (B, V, A), got (3,)"),
    ("attributes", lambda: V.attributes(np.zeros((3, 3, 2)), 2), "attr",
     "attr has a batch of 3, rast of 2"),
    ("attributes", lambda: V.attributes([[np.inf]], 1), "attr", "attr must be finite"),
    ("finite_array", lambda: V.finite_array("tex", np.array(["a"])), "tex",
     "must hold real numbers"),
    ("finite_array", lambda: V.finite_array("tex", [1.0, np.inf]), "tex",
     "tex must be finite, got NaN or Inf at index (1,)"),
    ("finite_array", lambda: V.finite_array("uv", [1e39], np.float32), "uv",
     "a value beyond float32"),
    ("float_array", lambda: V.float_array("eye", "abc", (3,)), "eye",
     "eye must be a numeric array of shape (3,)"),
    ("float_array", lambda: V.float_array("eye", [1, 2], (3,)), "eye",
     "eye must have shape (3,), got (2,)"),
    ("float_array", lambda: V.float_array("pts", [[1, np.nan]], (-1, 2)), "pts",
     "pts must be finite"),
    ("matrix4", lambda: V.matrix4("view", np.eye(3)), "view", "view must have shape (4, 4)"),
    ("intrinsics", lambda: V.intrinsics([[1, 0, 0], [1, 1, 0], [0, 0, 1]]), "K",
     "K must be an upper-triangular pinhole matrix"),
    ("intrinsics", lambda: V.intrinsics([[-1, 0, 0], [0, 1, 0], [0, 0, 1]]), "K",
     "K must have fx > 0 and fy > 0"),
    ("sample_positions", lambda: V.sample_positions(np.zeros((2, 2)), 4), "sample_positions",
     "sample_positions must have shape (4, 2)"),
    ("sample_positions", lambda: V.sample_positions(None, 4), "sample_positions",
     "got None"),
    ("sample_positions", lambda: V.sample_positions([[0.5, 1.0]], 1), "sample_positions",
     "sample_positions must be offsets inside the pixel"),
    ("resolution", lambda: V.resolution(8), "resolution", "resolution must be (height, width)"),
    ("resolution", lambda: V.resolution((8, 2.0)), "resolution",
     "resolution width must be an integer"),
    ("resolution", lambda: V.resolution((0, 8)), "resolution", "resolution height must be > 0"),
    ("resolution", lambda: V.resolution((8, 9), max_size=8), "resolution",
     "resolution width 9 exceeds the driver's maximum of 8"),
    ("outputs", lambda: V.outputs(5), "outputs", "outputs must be a sequence of names"),
    ("outputs", lambda: V.outputs(["normals"]), "outputs", "outputs has unknown names"),
    ("outputs", lambda: V.outputs([]), "outputs", "outputs must name at least one"),
    ("choice", lambda: V.choice("filter_mode", "cubic", ("linear", "nearest")), "filter_mode",
     "filter_mode must be one of ('linear', 'nearest'), got 'cubic'"),
    ("choice", lambda: V.choice("filter_mode", ["linear"], ("linear",)), "filter_mode",
     "got ['linear']"),
    ("space", lambda: V.space("ndc"), "space", "space must be one of ('persp', 'screen')"),
    ("space", lambda: V.space(None), "space", "got None"),
    ("interpolation", lambda: V.interpolation("middle"), "interpolation",
     "interpolation must be one of"),
    ("interpolation", lambda: V.interpolation(1), "interpolation", "got 1"),
    ("real", lambda: V.real("near", "x"), "near", "near must be a real number, got 'x'"),
    ("real", lambda: V.real("near", float("inf")), "near", "near must be finite"),
    ("real", lambda: V.real("near", 0, positive=True), "near", "near must be > 0, got 0.0"),
    ("positive_int", lambda: V.positive_int("count", True), "count",
     "count must be a positive integer, got True"),
    ("positive_int", lambda: V.positive_int("count", 0), "count", "got 0"),
    ("samples", lambda: V.samples(3), "samples", "samples must be a power of two >= 1"),
    ("samples", lambda: V.samples(True), "samples", "got True"),
    ("samples", lambda: V.samples(8, offered=(1, 4), where=" here"), "samples",
     "samples=8 is not offered here: choose one of (1, 4)"),
    ("diff_attrs", lambda: V.diff_attrs("some", 3), "diff_attrs",
     "diff_attrs must be None, 'all' or a list of attribute indices"),
    ("diff_attrs", lambda: V.diff_attrs(7, 3), "diff_attrs", "got 7"),
    ("diff_attrs", lambda: V.diff_attrs([0, 1.0], 3), "diff_attrs",
     "diff_attrs must hold integer attribute indices, got 1.0"),
    ("diff_attrs", lambda: V.diff_attrs([3], 3), "diff_attrs",
     "diff_attrs index 3 is out of range for attr with 3 attributes"),
]


@pytest.mark.parametrize("check, call, argument, words", BAD_INPUTS,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(BAD_INPUTS)])
def test_every_check_names_its_argument(check, call, argument, words):
    with pytest.raises(ArgumentError) as err:
        call()
    assert err.value.argument == argument
    assert isinstance(err.value, ValueError)
    assert words in str(err.value), str(err.value)
    assert str(err.value).startswith(argument), str(err.value)   # the wording convention


def test_every_public_check_is_in_the_table():
    """A check added to glraster.validate without a row above fails here."""
    public = {name for name in dir(V) if not name.startswith("_") and callable(getattr(V, name))
              and getattr(getattr(V, name), "__module__", "") == V.__name__}
    assert public == {row[0] for row in BAD_INPUTS}


def test_good_input_passes_through_converted():
    assert V.positions([[0, 0, 0, 1]]).dtype == np.float32
    assert V.batched_positions(np.zeros((2, 3, 4), np.float32)).dtype == np.float64
    assert V.triangles(np.zeros((0, 3)), 0).shape == (0, 3)
    assert V.ranges(None, 3, 2) is None
    assert V.ranges([[0, 2], [2, 1]], 3, 2).tolist() == [[0, 2], [2, 1]]
    assert V.diff_attrs("all", 2) == (0, 1) and V.diff_attrs(None, 2) is None
    assert V.outputs(("depth", "persp")) == ("persp", "depth")
    assert V.resolution(np.array([4, 5])) == (4, 5)
    assert V.choice("mode", "a", ("a", "b")) == "a"


def test_rast_ids_errors_name_rast():
    """diff.layout.rast_ids names ``rast`` for a bad id channel, whatever the cause."""
    from glraster.diff import layout

    with pytest.raises(ArgumentError) as err:
        layout.rast_ids(np.full((1, 1, 1, 4), 0.5, np.float32), 3)
    assert err.value.argument == "rast" and "rast channel 3 (triangle id)" in str(err.value)
    with pytest.raises(ArgumentError) as err:
        layout.rast_ids(np.full((1, 1, 1, 4), 9.0, np.float32), 3)
    assert err.value.argument == "rast" and "beyond tri's 3 triangles" in str(err.value)


@pytest.mark.parametrize("kwargs, argument", [
    ({"pos": np.zeros((3, 3))}, "pos"),
    ({"tri": [[0, 1, 5]]}, "tri"),
    ({"resolution": (0, 8)}, "resolution"),
    ({"outputs": ("normals",)}, "outputs"),
    ({"method": "magic"}, "method"),
    ({"samples": 3}, "samples"),
    ({"interpolation": "middle"}, "interpolation"),
    ({"cull": "sometimes"}, "cull"),
    ({"affine": True}, "affine"),
    ({"out": "a raster"}, "out"),
    ({"shader_files": {"vert": "x"}, "method": "divw"}, "shader_files"),
])
def test_rasterize_errors_name_the_argument(ctx, kwargs, argument):
    args = {"pos": GOOD_POS, "tri": GOOD_TRI, "resolution": (8, 8), **kwargs}
    with pytest.raises(ArgumentError) as err:
        gr.rasterize(args.pop("pos"), args.pop("tri"), args.pop("resolution"), ctx=ctx, **args)
    assert err.value.argument == argument, str(err.value)


@pytest.mark.parametrize("kwargs, argument", [
    ({"pos": np.zeros((3, 3))}, "pos"),
    ({"tri": [[0, 1, 5]]}, "tri"),
    ({"resolution": (8,)}, "resolution"),
    ({"fill_rule": "topleft"}, "fill_rule"),
    ({"edge_band_px": -1}, "edge_band_px"),
    ({"samples": 6}, "samples"),
])
def test_reference_errors_name_the_argument(kwargs, argument):
    args = {"pos": GOOD_POS, "tri": GOOD_TRI, "resolution": (8, 8), **kwargs}
    with pytest.raises(ArgumentError) as err:
        gr.reference.rasterize(args.pop("pos"), args.pop("tri"), args.pop("resolution"), **args)
    assert err.value.argument == argument, str(err.value)


@pytest.mark.parametrize("kwargs, argument, words", [
    ({"space": "ndc"}, "space", "space must be one of"),
    ({"attr": None}, "attr", "attr is None"),
    ({"attr": np.array(["a", "b", "c"])}, "attr", "attr must hold real numbers"),
    ({"attr": np.ones((3, 2, 2))}, "attr", "attr must have shape (V, C) or (V,)"),
    ({"attr": np.array([[0.0], [np.nan], [1.0]])}, "attr", "attr must be finite"),
    ({"tri": [[0, 1, 3]]}, "tri", "tri index 3 is out of range for attr with 3 rows"),
    ({"tri": [[0, 1]]}, "tri", "tri must have shape (T, 3)"),
    ({"tri": np.zeros((1, 3))}, "tri", "tri must have an integer dtype"),
    ({"tri": np.zeros((0, 3), int)}, "raster", "raster.tri_id refers to triangle 0"),
    ({"raster": "not a raster"}, "raster", "raster has no 'persp' barycentrics"),
])
def test_interpolate_errors_name_the_argument(kwargs, argument, words):
    raster = gr.reference.rasterize(GOOD_POS, GOOD_TRI, (8, 8), outputs=("persp", "tri_id"))
    args = {"attr": np.ones((3, 1)), "raster": raster, "tri": GOOD_TRI, **kwargs}
    with pytest.raises(ArgumentError) as err:
        gr.interpolate(args.pop("attr"), args.pop("raster"), args.pop("tri"), **args)
    assert err.value.argument == argument and words in str(err.value), str(err.value)


def test_a_context_that_is_not_one_names_ctx():
    """ctx takes a glraster.Context (or None for the default); a backend name there is
    an ArgumentError naming ctx, before any GL work, not an AttributeError from deep inside."""
    with pytest.raises(ArgumentError) as err:
        gr.rasterize(GOOD_POS, GOOD_TRI, (8, 8), ctx="egl")
    assert err.value.argument == "ctx"
    assert str(err.value) == "ctx must be a glraster.Context or None, got str 'egl'"
