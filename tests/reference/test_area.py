"""Exact area coverage (glraster.reference.area) against an independent polygon clipper
and against values computed by hand.

The independent path: each triangle is clipped to the view volume in exact rational
arithmetic (fractions.Fraction, a separate Sutherland-Hodgman written here), projected
exactly and only then rounded to float64; shapely (GEOS) forms the union of those
polygons (or the painter's differences, for visible areas) and intersects it with every
pixel square. Tolerance 1e-12 of a pixel's area: both sides round each coordinate of a
window-space point once or a few times (about 1e-16 relative, 1e-14 px at 64 px), and an
area is a sum of a few products of such coordinates; 1e-12 leaves a margin of 100 over
that while a real mistake (a missed slab, a wrong side of a clip, a wrong depth order)
moves areas by far more.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

shapely = pytest.importorskip("shapely")
from shapely import geometry as sg  # noqa: E402

from glraster import reference  # noqa: E402
from glraster.geometry.window import window_to_clip  # noqa: E402
from glraster.reference.area import area_coverage, visible_area  # noqa: E402

PIXEL_TOL = 1e-12


# --------------------------------------------------------------------------- the independent path


def _clip_exact(vertices):
    """Sutherland-Hodgman of one triangle, rows (x, y, z, w) as Fractions, against
    -w <= x, y, z <= w."""
    poly = [tuple(Fraction(float(c)) for c in v) for v in vertices]
    for axis in range(3):
        for sign in (1, -1):
            out = []
            for i, a in enumerate(poly):
                b = poly[(i + 1) % len(poly)]
                da, db = a[3] + sign * a[axis], b[3] + sign * b[axis]
                if da >= 0:
                    out.append(a)
                if (da >= 0) != (db >= 0):
                    s = da / (da - db)
                    out.append(tuple(p + (q - p) * s for p, q in zip(a, b)))
            poly = out
            if not poly:
                return []
    return poly


def _window_polygon(vertices, resolution):
    """shapely Polygon of a triangle's visible part in window coordinates, or None."""
    height, width = resolution
    poly = _clip_exact(vertices)
    if len(poly) < 3 or any(p[3] <= 0 for p in poly):
        return None
    pts = [(float((p[0] / p[3] + 1) * width / 2), float((p[1] / p[3] + 1) * height / 2))
           for p in poly]
    shape = sg.Polygon(pts)
    return shape if shape.area > 0 else None


def _pixel_boxes(resolution):
    height, width = resolution
    y, x = np.mgrid[0:height, 0:width]
    return shapely.box(x.ravel(), y.ravel(), x.ravel() + 1, y.ravel() + 1)


def _shapely_union_area(pos, tri, resolution):
    pos32 = np.asarray(pos, np.float32)
    polys = [p for p in (_window_polygon(pos32[t], resolution) for t in tri) if p is not None]
    union = shapely.union_all(polys)
    return shapely.area(shapely.intersection(union, _pixel_boxes(resolution))).reshape(resolution)


def _dense(fragments, n_tri):
    height, width = fragments.resolution
    out = np.zeros((height, width, n_tri))
    out[fragments.y, fragments.x, fragments.tri_id] = fragments.area
    return out


# --------------------------------------------------------------------------- scenes


def _random_window_triangles(rng, n, resolution, size, w_range=(1.0, 1.0)):
    """n triangles around random centres in the window (sides about ``size`` px), each
    vertex given a random w (perspective) and z in (-w, w)."""
    height, width = resolution
    centre = rng.uniform([0, 0], [width, height], (n, 1, 2))
    xy = (centre + rng.uniform(-size, size, (n, 3, 2))).reshape(-1, 2)
    w = rng.uniform(*w_range, len(xy))
    pos = window_to_clip(xy, resolution, z_ndc=rng.uniform(-0.9, 0.9, len(xy)), w=w)
    return pos, np.arange(len(xy)).reshape(-1, 3)


@pytest.mark.parametrize("w_range", [(1.0, 1.0), (0.2, 20.0)], ids=["affine", "perspective"])
def test_random_overlapping_triangles_match_shapely_union(w_range):
    rng = np.random.default_rng(17)
    res = (24, 32)
    pos, tri = _random_window_triangles(rng, 16, res, 9.0, w_range)
    ours = area_coverage(pos, tri, res)
    theirs = _shapely_union_area(pos, tri, res)
    assert 0.2 < ours.mean() < 0.9                      # the scene overlaps, not empty/full
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=PIXEL_TOL)


def test_sliver_triangles_match_shapely():
    # long triangles 1e-3 px to 0.3 px wide at many angles, some crossing each other
    rng = np.random.default_rng(3)
    res = (32, 32)
    rows = []
    for _ in range(12):
        a = rng.uniform([2, 2], [30, 30])
        b = rng.uniform([2, 2], [30, 30])
        d = b - a
        normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        c = (a + b) / 2 + normal * 10.0 ** rng.uniform(-3, -0.5)
        rows += [a, b, c]
    pos = window_to_clip(np.array(rows), res, z_ndc=rng.uniform(-0.5, 0.5, len(rows)))
    tri = np.arange(len(rows)).reshape(-1, 3)
    ours = area_coverage(pos, tri, res)
    np.testing.assert_allclose(ours, _shapely_union_area(pos, tri, res), rtol=0, atol=PIXEL_TOL)
    assert 0 < ours.sum() < 50


def test_near_clipped_and_behind_the_eye_triangles_match_shapely():
    # clip-space vertices with w in [-1, 3] and z beyond both planes: every triangle crosses
    # the near plane, the far plane or w = 0 somewhere; the exact clipper decides the rest
    rng = np.random.default_rng(5)
    res = (20, 28)
    w = rng.uniform(-1.0, 3.0, 60)
    xy = rng.uniform(-1.5, 1.5, (60, 2)) * np.abs(w)[:, None]
    z = rng.uniform(-2.0, 2.0, 60) * np.abs(w)
    pos = np.c_[xy, z, w]
    tri = np.arange(60).reshape(-1, 3)
    ours = area_coverage(pos, tri, res)
    theirs = _shapely_union_area(pos, tri, res)
    assert theirs.sum() > 20                      # something survives the clipping
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=PIXEL_TOL)


def test_floor_receding_behind_the_camera_matches_shapely():
    # a ground plane from under the camera to far away: its near triangles cross the near
    # plane (and w = 0) and are clipped before the divide
    from glraster.geometry import camera as cam

    res = (24, 32)
    xs, zs = np.meshgrid(np.linspace(-4, 4, 5), np.linspace(2, -30, 5))
    verts = np.c_[xs.ravel(), np.full(xs.size, -1.0), zs.ravel()]
    view = cam.look_at([0.0, 0.0, 0.0], [0.0, -0.3, -1.0], [0.0, 1.0, 0.0])
    proj = cam.perspective(60.0, res[1] / res[0], 0.5, 20.0)
    pos = cam.project(verts, None, view, proj)
    assert (pos[:, 3] < 0).any() and (pos[:, 2] > pos[:, 3]).any()   # behind, beyond far
    quads = [(r * 5 + c, r * 5 + c + 1, (r + 1) * 5 + c + 1, (r + 1) * 5 + c)
             for r in range(4) for c in range(4)]
    tri = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    ours = area_coverage(pos, tri, res)
    np.testing.assert_allclose(ours, _shapely_union_area(pos, tri, res), rtol=0, atol=PIXEL_TOL)


# --------------------------------------------------------------------------- visible areas


def test_visible_areas_of_flat_layers_match_painters_differences():
    # triangles parallel to the screen at distinct depths: what each shows is its polygon
    # minus the union of those in front (shapely differences)
    rng = np.random.default_rng(11)
    res = (20, 24)
    n = 10
    pos, tri = _random_window_triangles(rng, n, res, 8.0)
    depth = rng.permutation(n) / n * 1.6 - 0.8
    pos[:, 2] = np.repeat(depth, 3) * pos[:, 3]
    frags = visible_area(pos, tri, res)
    ours = _dense(frags, n)
    boxes = _pixel_boxes(res)
    polys = [_window_polygon(np.float32(pos[t]), res) for t in tri]
    front = sg.Polygon()
    for t in np.argsort(depth):
        shown = shapely.intersection(polys[t].difference(front), boxes)
        np.testing.assert_allclose(ours[..., t].ravel(), shapely.area(shown), rtol=0,
                                   atol=PIXEL_TOL, err_msg=f"triangle {t}")
        front = front.union(polys[t])
    np.testing.assert_allclose(frags.coverage, _shapely_union_area(pos, tri, res), rtol=0,
                               atol=PIXEL_TOL)


def test_intersecting_triangles_split_along_their_line_of_equal_depth():
    # two triangles that pass through each other: where both are, each is in front on one
    # side of the line where their depths are equal (a half-plane, cut with shapely);
    # elsewhere each shows alone
    res = (16, 16)
    xy = np.array([[1.0, 2.0], [15.0, 3.5], [6.0, 14.0], [2.5, 12.0], [14.0, 1.0], [13.0, 13.0]])
    z = np.array([-0.8, 0.6, 0.1, 0.7, -0.5, -0.2])
    pos = window_to_clip(xy, res, z_ndc=z)
    tri = np.array([[0, 1, 2], [3, 4, 5]])
    ours = _dense(visible_area(pos, tri, res), 2)
    # window depth planes from the float32 vertices, solved in float64
    win = reference.area.window_polygons(pos, tri, res)
    (a0, b0, c0), (a1, b1, c1) = win[2]
    polys = [_window_polygon(np.float32(pos[t]), res) for t in tri]
    # half-plane where triangle 1 is strictly nearer: (a1-a0) x + (b1-b0) y + (c1-c0) < 0,
    # a big quadrilateral on that side of the line of equal depth
    n = np.array([a1 - a0, b1 - b0])
    c = c1 - c0
    foot = -c * n / (n @ n)                       # the line's point nearest the origin
    along = np.array([-n[1], n[0]]) / np.linalg.norm(n) * 1e3
    down = -n / np.linalg.norm(n) * 1e3
    nearer1 = sg.Polygon([foot - along, foot + along, foot + along + down, foot - along + down])
    boxes = _pixel_boxes(res)
    shown1 = shapely.area(shapely.intersection(polys[1].difference(
        polys[0].difference(nearer1)), boxes))
    shown0 = shapely.area(shapely.intersection(polys[0].difference(
        polys[1].intersection(nearer1)), boxes))
    assert shown0.sum() > 10 and shown1.sum() > 10
    np.testing.assert_allclose(ours[..., 0].ravel(), shown0, rtol=0, atol=PIXEL_TOL)
    np.testing.assert_allclose(ours[..., 1].ravel(), shown1, rtol=0, atol=PIXEL_TOL)


def test_depth_ties_keep_the_earlier_triangle():
    # the same triangle twice: the first drawn shows everywhere, the second nowhere (LESS)
    res = (8, 8)
    pos = window_to_clip(np.array([[1.0, 1.0], [7.0, 2.0], [3.0, 7.0]]), res, z_ndc=0.25)
    frags = visible_area(pos, [[0, 1, 2], [0, 1, 2]], res)
    assert set(frags.tri_id.tolist()) == {0}
    assert frags.area.sum() == pytest.approx(0.5 * abs(6 * 6 - 1 * 2), abs=1e-12)


# --------------------------------------------------------------------------- exact values


def test_half_pixel_triangle_covers_exactly_half_of_one_pixel():
    res = (8, 8)
    pos = window_to_clip(np.array([[2.0, 3.0], [3.0, 3.0], [3.0, 4.0]]), res)
    area = area_coverage(pos, [[0, 1, 2]], res)
    assert area[3, 2] == 0.5                      # exact: every coordinate is a pixel corner
    assert np.count_nonzero(area) == 1


def test_full_screen_quad_covers_every_pixel_fully():
    res = (9, 13)
    pos = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], float)
    area = area_coverage(pos, [[0, 1, 2], [0, 2, 3]], res)
    # the diagonal's pixels are the sum of two slab areas: a few float64 ulps of 1 (1e-15)
    np.testing.assert_allclose(area, 1.0, rtol=0, atol=1e-15)


def test_a_quad_larger_than_the_view_volume_is_clipped_to_the_viewport():
    res = (6, 10)
    pos = np.array([[-3, -2, 0, 1], [5, -2, 0, 1], [5, 4, 0, 1], [-3, 4, 0, 1]], float)
    np.testing.assert_allclose(area_coverage(pos, [[0, 1, 2], [0, 2, 3]], res), 1.0, atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_pixel_areas_sum_to_the_window_space_area(seed):
    # triangles inside the viewport, back-facing ones included: the sum over pixels is the
    # shoelace area of the float32 window positions (relative 1e-12: a few roundings per
    # pixel over up to a few hundred pixels)
    rng = np.random.default_rng(seed)
    res = (40, 56)
    xy = rng.uniform([0.5, 0.5], [55.5, 39.5], (3, 2))
    w = rng.uniform(0.3, 5.0, 3)
    pos = np.float32(window_to_clip(xy, res, z_ndc=rng.uniform(-0.9, 0.9, 3), w=w))
    p = pos.astype(np.float64)
    win = np.c_[(p[:, 0] / p[:, 3] + 1) * res[1] / 2, (p[:, 1] / p[:, 3] + 1) * res[0] / 2]
    e1, e2 = win[1] - win[0], win[2] - win[0]
    expected = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
    assert area_coverage(pos, [[0, 1, 2]], res).sum() == pytest.approx(expected, rel=1e-12)


def test_triangle_entirely_behind_the_eye_covers_nothing():
    res = (8, 8)
    pos = np.array([[0.5, 0.5, 0.0, -1.0], [-0.5, 0.5, 0.0, -1.0], [0.0, -0.5, 0.0, -1.0]])
    assert not area_coverage(pos, [[0, 1, 2]], res).any()


def test_resolve_gives_the_exact_box_filtered_colours():
    # two flat colours on the two halves of a square split by its diagonal, over a background
    res = (4, 4)
    pos = window_to_clip(np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]]), res)
    frags = visible_area(pos, [[0, 1, 2], [0, 2, 3]], res)
    image = frags.resolve(np.array([[1.0, 0.0], [0.0, 1.0]]), background=[0.5, 0.5])
    # pixel (1, 1) is cut by the diagonal: half of each colour
    np.testing.assert_allclose(image[1, 1], [0.5, 0.5], atol=1e-15)
    np.testing.assert_allclose(image[1, 2], [1.0, 0.0], atol=1e-15)   # below the diagonal
    np.testing.assert_allclose(image[2, 1], [0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(image[0, 0], [0.5, 0.5], atol=0)       # background only
    with pytest.raises(ValueError, match="tri_values has 1 rows"):
        frags.resolve(np.ones(1))


def test_bad_arguments_name_what_is_wrong():
    with pytest.raises(ValueError, match=r"pos must have shape \(V, 4\)"):
        area_coverage(np.zeros((3, 3)), [[0, 1, 2]], (4, 4))
    with pytest.raises(ValueError, match="tri index 3 is out of range"):
        area_coverage(np.zeros((3, 4)), [[0, 1, 3]], (4, 4))
    with pytest.raises(ValueError, match="resolution width must be > 0"):
        area_coverage(np.zeros((3, 4)), [[0, 1, 2]], (4, 0))
    assert area_coverage(np.zeros((0, 4)), np.zeros((0, 3), int), (3, 5)).shape == (3, 5)
