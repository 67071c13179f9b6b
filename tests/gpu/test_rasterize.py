"""GPU rasterization against the float64 reference, on every available backend.

Tolerances: coverage and triangle ids are compared exactly (llvmpipe's fill rule is modeled
bit for bit; clipped triangles get the edge band); values are compared against the
per-pixel bound of glraster.verify.tolerance (report.ok()), whose derivation is in
docs/tolerance.md.
"""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster.geometry import synthetic
from glraster.verify.tolerance import ErrorModel, value_tolerance

RES = (256, 256)


def render_both(ctx, pos, tri, res=RES, outputs=gr.types.OUTPUTS):
    gpu = gr.rasterize(pos, tri, res, ctx=ctx, outputs=outputs)
    ref = gr.reference.rasterize(pos, tri, res, fill_rule="llvmpipe" if ctx.is_llvmpipe else None)
    return gpu, ref, gr.compare(gpu, ref, ErrorModel.for_context(ctx))


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_random_soup_matches_reference(ctx, seed):
    # 5 x 100 = 500 random triangles inside the viewport, w in [0.2, 20].
    pos, tri = synthetic.random_soup(100, seed=seed)
    gpu, ref, report = render_both(ctx, pos, tri)
    assert report.ok(), report.summary()
    if ctx.is_llvmpipe:  # the fill rule is modeled exactly: not even band mismatches
        assert report.coverage_mismatch_in_band == 0
        assert not ref.edge_band.any()
    # glraster's accuracy target for the bulk of pixels.
    assert report.values["persp"].p999 <= 1e-5
    assert report.values["screen"].p999 <= 1e-5


@pytest.mark.parametrize("size", [0.01, 0.03])
def test_tiny_and_sliver_triangles_within_per_pixel_tolerance(ctx, size):
    pos, tri = synthetic.random_soup(300, seed=7, size=size)
    _, _, report = render_both(ctx, pos, tri)
    assert report.ok(), report.summary()
    assert report.covered_ref > 0


@pytest.mark.parametrize("scene", ["grid", "fan", "aligned"])
def test_shared_edges_have_no_holes_and_no_double_hits(ctx, scene):
    """Each triangle drawn alone: the coverage counts sum to exactly 1 inside the mesh."""
    if scene == "grid":
        pos, tri = synthetic.grid(6, 6, seed=3, w_range=(0.5, 4.0))
        res = (96, 96)
    elif scene == "fan":
        pos, tri = synthetic.fan(40, center=(0.013, -0.021))
        res = (96, 96)
    else:  # vertices on pixel centers: many centers exactly on shared edges
        res = (64, 64)
        pos, tri = synthetic.pixel_aligned_mesh(res, step=8)
    hits = np.zeros(res, int)
    for k in range(len(tri)):
        hits += gr.rasterize(pos, tri[k:k + 1], res, ctx=ctx, outputs=("tri_id",)).mask
    whole = gr.rasterize(pos, tri, res, ctx=ctx)
    assert hits.max() == 1, "a pixel was produced by two triangles"
    np.testing.assert_array_equal(hits == 1, whole.mask)
    if scene == "grid":
        assert whole.mask.all(), "the grid covers the viewport: no holes"
    _, ref, report = render_both(ctx, pos, tri, res)
    assert report.ok(), report.summary()


def test_pixel_aligned_mesh_matches_fill_rule_exactly(ctx):
    res = (100, 130)
    pos, tri = synthetic.pixel_aligned_mesh(res, step=7)
    gpu, ref, report = render_both(ctx, pos, tri, res)
    if ctx.is_llvmpipe:
        np.testing.assert_array_equal(gpu.tri_id, ref.tri_id)
    assert report.ok(), report.summary()


def _clip_soup(seed, count=200, behind=False):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1, 1, (3 * count, 4))
    pos[:, 3] = rng.uniform(0.2, 5, 3 * count)
    pos[:, :2] *= pos[:, 3:4] * 1.5
    pos[:, 2] = rng.uniform(-3, 3, 3 * count) * pos[:, 3]
    if behind:
        pos[::3, 3] *= -1
    return pos.astype(np.float32), np.arange(3 * count).reshape(count, 3)


@pytest.mark.parametrize("behind", [False, True], ids=["near_far_crossing", "behind_camera"])
def test_clipped_triangles_match_unclipped_formula(ctx, behind):
    pos, tri = _clip_soup(11, behind=behind)
    gpu, ref, report = render_both(ctx, pos, tri)
    assert report.ok(), report.summary()
    assert report.covered_ref > 10000
    # persp and depth are judged everywhere; screen only where the documented llvmpipe
    # deviation (two or more clip planes) does not apply.
    assert report.values["persp"].pixels == report.values["depth"].pixels > 10000


def test_single_plane_clipping_keeps_noperspective_exact(ctx):
    """Near-plane clipping alone: GL's screen-linear rule holds on llvmpipe, no waiver."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        pos = rng.uniform(-1, 1, (3, 4))
        pos[:, 3] = rng.uniform(0.5, 3, 3)
        pos[:, :2] *= pos[:, 3:4] * 0.8
        pos[:, 2] = rng.uniform(-0.5, 0.5, 3) * pos[:, 3]
        pos[0, 2] = -1.8 * pos[0, 3]  # vertex 0 in front of the near plane
        gpu, ref, report = render_both(ctx, pos.astype(np.float32), [[0, 1, 2]])
        assert report.values["screen"].waived == 0
        assert report.ok(), report.summary()


def test_degenerate_triangles_produce_nothing(ctx):
    pos = np.array([[0, 0, 0, 1], [0.5, 0.5, 0, 1], [1, 1, 0, 1],       # collinear
                    [0.2, 0.1, 0, 1], [0.2, 0.1, 0, 1], [0.9, -0.3, 0, 1],  # repeated vertex
                    [-0.5, -0.5, 0, 1], [-0.5 + 1e-4, -0.5, 0, 1], [-0.5, -0.5 + 1e-4, 0, 1]],
                   np.float32)  # smaller than 1/256 px: snaps to zero area on llvmpipe
    tri = [[0, 1, 2], [3, 4, 5], [0, 0, 0], [6, 7, 8]]
    gpu, ref, report = render_both(ctx, pos, tri)
    assert not gpu.mask.any() and not ref.mask.any()


def test_equal_w_makes_persp_equal_screen(ctx):
    pos, tri = synthetic.random_soup(100, seed=3, w_range=(2.5, 2.5))
    gpu, ref, report = render_both(ctx, pos, tri)
    assert report.ok(), report.summary()
    # In the reference they are the same numbers up to float64 rounding.
    np.testing.assert_allclose(ref.persp, ref.screen, rtol=0, atol=1e-12)
    # On the GPU each is within its own tolerance of that common value.
    tol = value_tolerance(ref.triangles, ref.tri_id, ("persp", "screen"))
    both = gpu.mask & ref.mask & ~ref.depth_tie
    assert (np.abs(gpu.persp - gpu.screen)[both] <= (tol.persp + tol.screen)[both]).all()


def test_depth_order_nearest_wins_and_ties_keep_the_earlier(ctx):
    near = [[-0.8, -0.8, -0.5, 1], [0.8, -0.8, -0.5, 1], [0, 0.8, -0.5, 1]]
    far = [[-0.9, -0.7, 0.5, 1], [0.9, -0.7, 0.5, 1], [0, 0.9, 0.5, 1]]
    pos = np.array(near + far + near, np.float32)
    for tri, winner in (([[0, 1, 2], [3, 4, 5]], 0), ([[3, 4, 5], [0, 1, 2]], 1),
                        ([[6, 7, 8], [3, 4, 5], [0, 1, 2]], 0)):
        gpu, ref, report = render_both(ctx, pos, tri)
        assert report.ok(), report.summary()
        assert gpu.tri_id[128, 128] == ref.tri_id[128, 128] == winner
        assert gpu.depth[128, 128] == pytest.approx(0.25, abs=1e-6)


def test_output_subsets_read_back_only_what_was_asked(ctx):
    pos, tri = synthetic.random_soup(50, seed=5)
    full = gr.rasterize(pos, tri, RES, ctx=ctx)
    for outputs in (("persp",), ("screen",), ("depth",), ("tri_id",), ("persp", "depth")):
        part = gr.rasterize(pos, tri, RES, ctx=ctx, outputs=outputs)
        assert part.outputs == outputs
        for name in ("persp", "screen", "depth", "tri_id"):
            if name in outputs:
                np.testing.assert_array_equal(getattr(part, name), getattr(full, name))
            else:
                assert getattr(part, name) is None
        np.testing.assert_array_equal(part.mask, full.mask)


def test_empty_triangle_list_gives_an_empty_image(ctx):
    pos = np.zeros((3, 4), np.float32)
    for tri in (np.zeros((0, 3), np.int32), []):
        r = gr.rasterize(pos, tri, (8, 12), ctx=ctx)
        assert r.persp.shape == (8, 12, 3) and r.depth.shape == (8, 12)
        assert not r.mask.any()
        assert (r.persp == 0).all() and (r.screen == 0).all()
        assert (r.depth == 1.0).all() and (r.tri_id == -1).all()
        assert r.persp.dtype == np.float32 and r.tri_id.dtype == np.int32


def test_row_zero_is_the_bottom_of_the_image(ctx):
    # A triangle in the lower half of NDC covers low row indices only.
    pos = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, -0.2, 0, 1]], np.float32)
    r = gr.rasterize(pos, [[0, 1, 2]], (64, 64), ctx=ctx)
    rows = np.flatnonzero(r.mask.any(1))
    assert rows.min() == 0 and rows.max() < 32


def test_triangle_ids_are_exact_past_2_pow_24(ctx):
    """Ids go through a 32-bit integer target: 2^24 + 1 is not representable in float32."""
    count = (1 << 24) + 2
    pos = np.array([[0, 0, 0, 1], [-0.5, -0.5, 0, 1], [0.5, -0.5, 0, 1], [0, 0.5, 0, 1]],
                   np.float32)
    tri = np.zeros((count, 3), np.int32)   # all degenerate (0, 0, 0) but the last
    tri[-1] = (1, 2, 3)
    r = gr.rasterize(pos, tri, (16, 16), ctx=ctx, outputs=("tri_id",))
    assert r.tri_id[8, 8] == count - 1 == 16777217


@pytest.mark.parametrize("w_range", [(1.0, 1.0), (0.5, 5.0)])
def test_large_jittered_grid_matches_fill_rule_exactly(ctx, w_range):
    """Thousands of vertices far from the origin: the snapped fixed-point vertices depend
    on the last float32 bit of the window position (llvmpipe fuses the viewport transform),
    so this catches a reference that rounds differently."""
    pos, tri = synthetic.grid(120, 90, seed=1, w_range=w_range)
    res = (600, 900)
    gpu = gr.rasterize(pos, tri, res, ctx=ctx, outputs=("tri_id",))
    ref = gr.reference.rasterize(pos, tri, res, outputs=("tri_id",),
                                 fill_rule="llvmpipe" if ctx.is_llvmpipe else None)
    differ = (gpu.tri_id != ref.tri_id) & ~ref.ambiguous
    assert differ.sum() == 0


# -- out=: caller-provided arrays --------------------------------------------------------

@pytest.mark.parametrize("method", ["hw", "homogeneous64"])
@pytest.mark.parametrize("same_w", [False, True])  # the affine path shares persp / screen
def test_out_fills_the_callers_arrays_with_the_same_values(ctx, method, same_w):
    """rasterize(out=r) writes into r's arrays (no new frame-sized arrays) and gives
    bit-identical results to a fresh call (exact: same draw, same readback)."""
    pos, tri = synthetic.random_soup(60, seed=3, w_range=(1.0, 1.0) if same_w else (0.5, 4.0))
    first = gr.rasterize(pos, tri, (48, 40), ctx=ctx, method=method)
    fresh = gr.rasterize(pos[::-1].copy(), tri, (48, 40), ctx=ctx,  # another image
                         method=method)
    again = gr.rasterize(pos, tri, (48, 40), ctx=ctx, method=method, out=fresh)
    for name in ("persp", "screen", "depth", "tri_id", "mask"):
        assert getattr(again, name) is getattr(fresh, name), name
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name), err_msg=name)


def test_out_with_a_subset_of_outputs(ctx):
    pos, tri = synthetic.random_soup(20, seed=4)
    want = gr.rasterize(pos, tri, (16, 24), ctx=ctx, outputs=("persp",))
    target = gr.rasterize(pos, tri, (16, 24), ctx=ctx, outputs=("persp", "tri_id"))
    got = gr.rasterize(pos, tri, (16, 24), ctx=ctx, outputs=("persp",), out=target)
    assert got.persp is target.persp and got.tri_id is None
    np.testing.assert_array_equal(got.persp, want.persp)


@pytest.mark.parametrize("change, message", [
    (lambda r: setattr(r, "persp", r.persp[:, :-1]), r"out.persp must be .* shape \(16, 24, 3\)"),
    (lambda r: setattr(r, "persp", r.persp.astype(np.float64)), r"out.persp must be .*float32"),
    (lambda r: setattr(r, "depth", None), r"out.depth must be an array"),
    (lambda r: setattr(r, "mask", np.zeros((16, 24), bool, order="F")),
     r"out.mask must be .*not C-contiguous"),
])
def test_out_with_wrong_arrays_is_a_value_error_naming_the_field(ctx, change, message):
    pos, tri = synthetic.random_soup(10, seed=5)
    r = gr.rasterize(pos, tri, (16, 24), ctx=ctx)
    change(r)
    with pytest.raises(ValueError, match=message):
        gr.rasterize(pos, tri, (16, 24), ctx=ctx, out=r)


def test_out_must_be_a_raster(ctx):
    with pytest.raises(ValueError, match="out must be a glraster.Raster"):
        gr.rasterize(np.zeros((3, 4)) + [0, 0, 0, 1], [[0, 1, 2]], (4, 4), ctx=ctx,
                     out={"persp": np.zeros((4, 4, 3), np.float32)})
