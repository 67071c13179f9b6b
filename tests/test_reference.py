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
    """Seed 002 / seed 003: screen-space barycentrics as ratios of signed areas."""
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


def test_coplanar_duplicates_are_a_depth_tie_won_by_the_first():
    pos = np.array([[-0.9, -0.9, 0.1, 1], [0.9, -0.9, 0.2, 1], [0, 0.9, 0.3, 1]], np.float32)
    ref = gr.reference.rasterize(np.concatenate([pos, pos]), [[0, 1, 2], [3, 4, 5]], (32, 32))
    assert (ref.tri_id[ref.mask] == 0).all()
    assert ref.depth_tie[ref.mask].all()


def test_large_triangles_are_processed_in_chunks(monkeypatch):
    import glraster.reference as reference
    pos = np.array([[-1, -1, 0, 1], [3, -1, 0, 1], [-1, 3, 0, 1]], np.float32)
    whole = reference.rasterize(pos, [[0, 1, 2]], (128, 128))
    monkeypatch.setattr(reference, "CHUNK_CANDIDATES", 1000)
    chunked = reference.rasterize(pos, [[0, 1, 2]], (128, 128))
    assert whole.mask.all()
    for name in ("persp", "screen", "depth", "tri_id"):
        np.testing.assert_array_equal(getattr(whole, name), getattr(chunked, name))
