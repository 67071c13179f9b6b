"""The float64 reference against independent formulas and exact values."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster.reference import llvmpipe_edges, setup


def window_xy(pos, resolution):
    h, w = resolution
    pos = np.asarray(pos, np.float64)
    return np.stack([(pos[:, 0] / pos[:, 3] + 1) * w / 2, (pos[:, 1] / pos[:, 3] + 1) * h / 2], 1)


def area_ratio_barycentrics(v, p):
    """Screen-space barycentrics as ratios of signed areas (Moebius 1827; GL 4.5 eq. 14.8)."""
    def area(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    total = area(v[0], v[1], v[2])
    return np.array([area(p, v[1], v[2]), area(v[0], p, v[2]), area(v[0], v[1], p)]) / total


def test_values_match_area_ratios_and_eq_14_9():
    res = (64, 80)
    pos = np.array([[-0.7, -0.6, -0.2, 1.0], [1.2, -0.9, 0.6, 3.0], [0.1, 2.4, 1.0, 4.0]],
                   np.float32)
    ref = gr.reference.rasterize(pos, [[0, 1, 2]], res)
    v = window_xy(pos, res)
    w = pos[:, 3].astype(np.float64)
    z_ndc = pos[:, 2].astype(np.float64) / w
    ys, xs = np.nonzero(ref.mask)
    assert len(ys) > 500
    for y, x in list(zip(ys, xs))[::37]:
        a = area_ratio_barycentrics(v, (x + 0.5, y + 0.5))
        np.testing.assert_allclose(ref.screen[y, x], a, rtol=0, atol=1e-13)  # float64 rounding
        persp = (a / w) / (a / w).sum()                                     # GL eq. 14.9
        np.testing.assert_allclose(ref.persp[y, x], persp, rtol=0, atol=1e-13)
        depth = (a * z_ndc).sum() * 0.5 + 0.5                               # GL eq. 14.10
        assert ref.depth[y, x] == pytest.approx(depth, abs=1e-13)


def test_clipped_triangle_keeps_the_unclipped_formula():
    # Vertex 0 lies beyond the near plane (z < -w) but w > 0 everywhere: the visible part
    # must carry the barycentrics of the whole triangle, not of the clipped polygon.
    res = (64, 64)
    pos = np.array([[-0.5, -0.5, -3.0, 1.0], [0.8, -0.4, 0.5, 1.0], [0.0, 0.9, 0.5, 1.0]],
                   np.float32)
    ref = gr.reference.rasterize(pos, [[0, 1, 2]], res)
    v = window_xy(pos, res)
    ys, xs = np.nonzero(ref.mask)
    for y, x in zip(ys[::11], xs[::11]):
        a = area_ratio_barycentrics(v, (x + 0.5, y + 0.5))
        np.testing.assert_allclose(ref.screen[y, x], a, atol=1e-13)
        z_ndc = (a * pos[:, 2].astype(np.float64) / pos[:, 3]).sum()
        assert -1 <= z_ndc <= 1  # the near-plane part was clipped away
    # The clipped part (z_ndc < -1) is missing: fewer pixels than the whole triangle.
    whole = gr.reference.rasterize(pos * np.array([1, 1, 0, 1], np.float32), [[0, 1, 2]], res)
    assert 0 < ref.mask.sum() < whole.mask.sum()


def test_vertex_behind_the_eye_is_handled_without_splitting():
    res = (64, 64)
    pos = np.array([[-0.5, -0.5, 0.0, 1.0], [0.5, -0.5, 0.0, 1.0], [0.0, 0.5, -0.5, -0.5]],
                   np.float32)
    ref = gr.reference.rasterize(pos, [[0, 1, 2]], res)
    assert ref.mask.any()
    s = ref.persp[ref.mask]
    np.testing.assert_allclose(s.sum(1), 1, atol=1e-12)
    assert (s >= -1e-12).all()  # clip-space barycentrics of visible points are >= 0
    assert np.isfinite(ref.depth).all() and (ref.depth[ref.mask] < 1).all()


def test_llvmpipe_fill_rule_is_bottom_left():
    # Two triangles sharing the vertical line x = 32 (a pixel-center column) and the
    # horizontal line y = 32: centers exactly on an edge go to the triangle to their right
    # (a left edge is inclusive) and above (a bottom edge is inclusive).
    res = (64, 64)
    c = (32.5 / 32) - 1  # NDC of window 32.5: the center of pixel column 32
    pos = np.array([[c, -1, 0, 1], [c, 1, 0, 1], [-1, -1, 0, 1], [1, -1, 0, 1]], np.float32)
    ref = gr.reference.rasterize(pos, [[0, 1, 2], [0, 3, 1]], res)
    assert ref.tri_id[5, 32] == 1       # on the shared edge: the right-hand triangle
    pos_h = np.array([[-1, c, 0, 1], [1, c, 0, 1], [-1, -1, 0, 1], [-1, 1, 0, 1]], np.float32)
    ref_h = gr.reference.rasterize(pos_h, [[0, 1, 2], [1, 0, 3]], res)
    assert ref_h.tri_id[32, 1] == 1     # on the shared edge: the upper triangle


def test_llvmpipe_edges_snap_and_cull_zero_area():
    window = np.array([[[0.5, 0.5], [10.5, 0.5], [0.5, 10.5]],
                       [[0.5, 0.5], [0.501, 0.5], [0.5, 0.501]]], np.float32)
    edges, ok = llvmpipe_edges(window)
    assert ok.tolist() == [True, False]  # the second snaps to one point
    dcdx, dcdy, c = edges[0].T
    assert sorted(np.abs(dcdx).tolist()) == [0, 2560, 2560]


def test_without_a_fill_rule_edge_centers_fall_in_the_band():
    res = (64, 64)
    c = (32.5 / 32) - 1
    pos = np.array([[c, -1, 0, 1], [c, 1, 0, 1], [-1, -1, 0, 1]], np.float32)
    ref = gr.reference.rasterize(pos, [[0, 1, 2]], res, fill_rule=None)
    assert ref.edge_band[:, 32].all()        # centers exactly on the edge x = 32.5
    assert not ref.edge_band[:, 20].any()    # far from every edge
    exact = gr.reference.rasterize(pos, [[0, 1, 2]], res)
    assert not exact.edge_band.any()         # modeled exactly: no band needed


def test_bounding_boxes_stay_inside_the_viewport():
    rng = np.random.default_rng(0)
    pos = rng.normal(0, 5, (300, 4)).astype(np.float32)
    ts = setup(pos, np.arange(300).reshape(100, 3).astype(np.int32), (40, 50), "llvmpipe")
    live = (ts.bbox[:, 1] >= ts.bbox[:, 0]) & (ts.bbox[:, 3] >= ts.bbox[:, 2])
    assert (ts.bbox[live][:, [0, 1]] >= 0).all() and (ts.bbox[live][:, [0, 1]] < 50).all()
    assert (ts.bbox[live][:, [2, 3]] >= 0).all() and (ts.bbox[live][:, [2, 3]] < 40).all()


def test_where_a_snapped_sliver_extrapolates_its_depth_it_is_a_depth_tie():
    # A sliver of float area 0.009 px^2 (from a 1M-triangle terrain at 4096x4096) snaps to
    # 1/256-px vertices with 9x that area: llvmpipe covers pixel centers that lie outside
    # its float triangle, where every depth plane set up from float32 vertices extrapolates
    # (sum |lambda| > 5 here; measured 3.8e-4 off in the terrain). There a triangle
    # 1e-4 behind may win on the GPU: a depth tie. Elsewhere the floor's pixels stay judged.
    res = (128, 64)
    sliver = np.array([[13.00195312, 40.15722656], [18.83056641, 55.19677734],
                       [33.11279297, 92.05224609]])
    depth = np.array([0.98427219, 0.98419955, 0.98408612])
    floor = np.array([[0.0, 0.0], [64.0, 0.0], [64.0, 128.0], [0.0, 128.0]])   # two triangles

    def clip(win, window_depth):
        ndc = win / np.array([res[1], res[0]]) * 2 - 1
        return np.concatenate([ndc, 2 * window_depth[:, None] - 1, np.ones((len(win), 1))], 1)
    pos = np.concatenate([clip(sliver, depth), clip(floor, np.full(4, 0.9843))]).astype(np.float32)
    tri = [[0, 1, 2], [3, 4, 5], [3, 5, 6]]
    ref = gr.reference.rasterize(pos, tri, res)
    s, _ = gr.reference.edge_values(ref.triangles, np.zeros(res[0] * res[1], int),
                                    np.tile(np.arange(res[1]), res[0]),
                                    np.repeat(np.arange(res[0]), res[1]))
    reach = np.abs(s * ref.triangles.clip[0, :, 3]).sum(1).reshape(res)   # sum |lambda|
    on_sliver = ref.mask & (ref.tri_id == 0)
    outside = on_sliver & (reach > 1 + 1e-6)
    assert outside.any() and reach[outside].max() > 5
    assert ref.depth_tie[outside].all()
    # a plain depth difference, not DEPTH_TIE, separates them there
    assert (0.9843 - ref.depth[outside]).min() > 10 * gr.reference.DEPTH_TIE
    assert not ref.depth_tie[ref.mask & (ref.tri_id > 0)].any()


def test_coplanar_duplicates_are_a_depth_tie_won_by_the_first():
    pos = np.array([[-0.9, -0.9, 0.1, 1], [0.9, -0.9, 0.2, 1], [0, 0.9, 0.3, 1]], np.float32)
    ref = gr.reference.rasterize(np.concatenate([pos, pos]), [[0, 1, 2], [3, 4, 5]], (32, 32))
    assert (ref.tri_id[ref.mask] == 0).all()
    assert ref.depth_tie[ref.mask].all()


def random_soup(seed, count, spread=1.5, w_range=(-0.3, 3.0)):
    """Triangles that overlap, cross the viewport border, the near/far planes and w = 0."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(0, spread, (3 * count, 4)).astype(np.float32)
    pos[:, 3] = rng.uniform(*w_range, 3 * count)
    return pos, np.arange(3 * count, dtype=np.int32).reshape(count, 3)


def brute_force(pos, tri, res, fill_rule):
    """Coverage and winners by testing every pixel of the viewport against every triangle
    with NumPy formulas (llvmpipe's edge inequalities in int64, or the float64 center test),
    keeping the first triangle of least depth: GL's LESS test in draw order."""
    h, w = res
    ts = setup(pos, tri, res, fill_rule)
    py, px = np.mgrid[0:h, 0:w].reshape(2, -1)
    best = np.full(h * w, np.inf)
    best_tri = np.full(h * w, -1)
    for t in range(len(tri)):
        if ts.culled[t]:
            continue
        depth = (ts.depth_plane[t, 0] * (px + 0.5) + ts.depth_plane[t, 1] * (py + 0.5)
                 + ts.depth_plane[t, 2])
        if ts.fixed_ok[t]:
            e = ts.fixed[t]
            covered = np.all([e[k, 2] - e[k, 0] * px * 256 + e[k, 1] * py * 256 >= 1
                              for k in range(3)], axis=0)
        else:
            s, _ = gr.reference.edge_values(ts, np.full(len(px), t), px, py)
            with np.errstate(invalid="ignore"):
                covered = (s >= 0).all(1) & (s.sum(1) > 0) & (np.abs(2 * depth - 1) <= 1)
        with np.errstate(invalid="ignore"):
            wins = covered & (depth.astype(np.float32) < 1) & (depth < best)
        best[wins] = depth[wins]
        best_tri[wins] = t
    return best_tri.reshape(res)


@pytest.mark.parametrize("fill_rule", ["llvmpipe", None])
def test_compiled_pixel_loops_match_brute_force_numpy(fill_rule):
    # Exact: both sides evaluate the same IEEE float64 formulas (no fast-math, no FMA) and
    # the same integer inequalities, so ids must agree on every pixel.
    pos, tri = random_soup(3, 150)
    res = (48, 64)
    ref = gr.reference.rasterize(pos, tri, res, fill_rule=fill_rule)
    expected = brute_force(pos, tri, res, fill_rule)
    assert (expected >= 0).sum() > 1000
    np.testing.assert_array_equal(ref.tri_id, expected)


def test_depth_test_does_not_depend_on_fragment_order():
    from glraster.reference import kernels
    pos, tri = random_soup(4, 300, w_range=(0.5, 3.0))
    res = (64, 64)
    ts = setup(pos, tri, res, "llvmpipe")
    spans = kernels.fixed_point_spans(np.flatnonzero(ts.fixed_ok), ts.fixed, ts.bbox)
    error = np.random.default_rng(1).uniform(0, 1e-3, (len(tri), 2))   # per-triangle bounds
    planes = ts.adj * (ts.clip[:, :, 3] / ts.det[:, None])[:, :, None]
    results = []
    for order in (np.arange(len(spans[0])), np.random.default_rng(0).permutation(len(spans[0]))):
        n = 64 * 64
        state = np.full(n, np.inf), np.full(n, -1), np.zeros(n), np.full(n, np.inf)
        kernels.depth_test(*(a[order] for a in spans), ts.depth_plane, planes, error, 64,
                           *state, 2)
        results.append(state)
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


def test_concurrent_calls_from_threads_give_the_same_result():
    # A rendering service may call the reference from several threads at once; the
    # compiled kernels release the GIL and the parallel value pass is serialized.
    from concurrent.futures import ThreadPoolExecutor
    pos, tri = random_soup(6, 400, w_range=(0.5, 3.0))
    alone = gr.reference.rasterize(pos, tri, (96, 128))
    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda _: gr.reference.rasterize(pos, tri, (96, 128)), range(8)))
    for r in results:
        for name in ("persp", "screen", "depth", "tri_id", "depth_tie", "edge_band"):
            np.testing.assert_array_equal(getattr(r, name), getattr(alone, name))
