"""The float64 reference of antialias (no GL): the topology hash, the blend against closed
forms and box coverage, its gradients against central differences, the range-keeping
weights, w <= 0, welding, and the ValueErrors, called through glraster.diff.ops.ANTIALIAS
as a front end calls it. Scenes here are shared with the GPU tests."""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff import antialias_reference as aar
from glraster.diff import topology_hash as topo
from glraster.diff.ops import ANTIALIAS, INTERPOLATE, RASTERIZE
from glraster.errors import ArgumentError
from glraster.geometry import camera, shapes

RES = (48, 64)


# --------------------------------------------------------------------------- the op


def antialias_forward(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, *,
                      convex=True, dtype=np.float64, ctx=None):
    """The antialias op as a front end runs it: ANTIALIAS.check, then the core of ``dtype``
    (float64: the reference, float32: the GPU); returns (out, saved)."""
    if isinstance(color, np.ndarray) and np.issubdtype(color.dtype, np.floating):
        color = color.astype(dtype)
    inputs, params = ANTIALIAS.check(color, rast, pos, tri=tri, topology_hash=topology_hash,
                                     pos_gradient_boost=pos_gradient_boost, convex=convex,
                                     ctx=ctx)
    (out,), saved = ANTIALIAS.core(dtype).forward(*inputs, **params)
    return out, saved


def antialias_backward(saved, grad_out, **options):
    """(grad_color, grad_pos) from the core that made ``saved``."""
    grad_color, grad_rast, grad_pos = ANTIALIAS.core(saved.color.dtype).backward(
        saved, grad_out, **options)
    assert grad_rast is None
    return grad_color, grad_pos


# --------------------------------------------------------------------------- scenes


def window_to_clip(xy, resolution, w=1.0, z=0.0):
    """(N, 2) window points as clip positions with the given w (and z)."""
    height, width = resolution
    xy = np.asarray(xy, np.float64)
    w = np.broadcast_to(np.asarray(w, np.float64), (len(xy),))
    z = np.broadcast_to(np.asarray(z, np.float64), (len(xy),))
    nx = 2 * xy[:, 0] / width - 1
    ny = 2 * xy[:, 1] / height - 1
    return np.stack([nx * w, ny * w, z * w, w], -1)


def f32(a):
    return np.asarray(a, np.float32).astype(np.float64)


def mesh_scene(resolution=RES, level=2, eye=(0.3, 0.4, 3.2), seed=0, fov=45.0):
    """An icosphere in perspective, per-vertex colours (pos float32-representable)."""
    height, width = resolution
    verts, faces = shapes.icosphere(level)
    mvp = camera.perspective(fov, width / height, 0.5, 10) @ camera.look_at(eye, (0, 0, 0))
    pos = f32(np.concatenate([verts, np.ones((len(verts), 1))], 1) @ mvp.T)
    rng = np.random.default_rng(seed)
    return pos, faces.astype(np.int32), rng.uniform(0.1, 1, (len(verts), 3))


def soup_scene(resolution=RES, count=12, seed=1, layered=False):
    """Independent triangles, overlapping, w in [0.6, 2] (every edge a boundary edge);
    ``layered``: each triangle at one depth z/w (no two interpenetrate)."""
    rng = np.random.default_rng(seed)
    n = 3 * count
    w = rng.uniform(0.6, 2.0, n)
    xy = rng.uniform(-0.9, 0.9, (n, 2)) * w[:, None]
    z = rng.uniform(-0.8, 0.8, (n, 1))
    if layered:
        z = np.repeat(np.linspace(-0.8, 0.8, count), 3)[:, None]
    pos = f32(np.concatenate([xy, z * w[:, None], w[:, None]], 1))
    return pos, np.arange(n).reshape(count, 3).astype(np.int32), rng.uniform(0, 1, (n, 3))


def behind_scene(resolution=RES):
    """A triangle with a vertex behind the eye (w < 0) crossing the image, over a quad."""
    pos = f32([[-0.6, -0.5, 0.2, 1.0], [0.7, -0.4, 0.3, 1.4], [0.3, 0.9, -0.2, -0.5],
               [-1.5, -1.5, 0.9, 1.0], [1.5, -1.5, 0.9, 1.0], [1.5, 1.5, 0.9, 1.0],
               [-1.5, 1.5, 0.9, 1.0]])
    tri = np.array([[0, 1, 2], [3, 4, 5], [3, 5, 6]], np.int32)
    colors = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [.2, .2, .2], [.3, .3, .3],
                       [.4, .4, .4], [.5, .5, .5]], np.float64)
    return pos, tri, colors


def shade(pos, tri, colors, resolution=RES):
    """(rast, colour image) from the float64 reference rasterizer and interpolation."""
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=resolution)
    (col, _), _ = INTERPOLATE.forward(colors, rast, tri=tri)
    return rast, col


SCENES = {"mesh": mesh_scene, "soup": soup_scene, "behind": behind_scene}


def clip_px(pos, resolution):
    """(V, 4) clip-space steps that move each vertex by 1 window pixel in x and y (and w by
    a comparable relative amount)."""
    height, width = resolution
    w = np.abs(pos[..., 3])
    return np.stack([2 * w / width, 2 * w / height, np.ones_like(w), 2 * w / width], -1)


def relative_error(analytic, numeric):
    scale = max(np.abs(numeric).max(), 1e-300)
    return np.abs(analytic - numeric) / np.maximum(np.abs(numeric), 1e-3 * scale)


# --------------------------------------------------------------------------- topology hash


def probe(table: np.ndarray, lo: int, hi: int):
    """The GPU's lookup, in Python: linear probing from the hash slot."""
    mask = len(table) - 1
    s = int(topo._hash(np.array([lo]), np.array([hi]), mask)[0])
    for _ in range(len(table)):
        row = table[s]
        if row[0] == topo.HASH_EMPTY:
            return None
        if row[0] == lo and row[1] == hi:
            return int(row[2]), int(row[3])
        s = (s + 1) & mask
    return None


def test_topology_hash_lists_each_edge_with_its_triangles():
    tri = np.array([[0, 1, 2], [2, 1, 3], [3, 1, 4], [0, 2, 5]], np.int32)
    th = aar.antialias_construct_topology_hash(tri)
    assert th.num_edges == 9
    start, count = th.lookup(np.array([1, 2, 1, 0, 4]), np.array([2, 1, 3, 4, 3]))
    assert count.tolist() == [2, 2, 2, 0, 1]
    # edge (1, 2) is edge 0 of triangle 0 (opposite vertex 0) and edge 2 of triangle 1
    # (opposite 3): entries 3 t + i
    assert sorted(th.entries[start[0]:start[0] + 2].tolist()) == [0, 5]
    assert sorted(th.opposite[start[0]:start[0] + 2].tolist()) == [0, 3]


def test_gpu_table_probe_finds_every_edge_and_no_other():
    _, tri, _ = mesh_scene(level=3)
    th = aar.antialias_construct_topology_hash(tri)
    table = th.table()
    assert len(table) >= 2 * th.num_edges and len(table) & (len(table) - 1) == 0
    lo, hi = th.keys // th.num_vertices, th.keys % th.num_vertices
    for e in range(th.num_edges):
        assert probe(table, int(lo[e]), int(hi[e])) == (int(th.start[e]), int(th.count[e]))
    rng = np.random.default_rng(0)
    keys = set(th.keys.tolist())
    misses = 0
    for a, b in rng.integers(0, th.num_vertices, (300, 2)):
        lo_, hi_ = min(a, b), max(a, b)
        if lo_ * th.num_vertices + hi_ not in keys:
            assert probe(table, int(lo_), int(hi_)) is None
            misses += 1
    assert misses > 200
    assert all(c == 2 for c in th.count)   # a closed manifold


def test_welding_joins_duplicated_vertices():
    verts, faces = shapes.icosphere(1)
    dup = verts[faces.ravel()]                      # every triangle its own three vertices
    tri = np.arange(len(dup)).reshape(-1, 3).astype(np.int32)
    plain = aar.antialias_construct_topology_hash(tri)
    welded = aar.antialias_construct_topology_hash(tri, pos=dup)
    assert set(plain.count.tolist()) == {1}
    assert welded.welded and set(welded.count.tolist()) == {2}
    assert welded.num_edges == aar.antialias_construct_topology_hash(faces).num_edges


# --------------------------------------------------------------------------- forward


def window_xy(pos, resolution):
    height, width = resolution
    return np.stack([(pos[:, 0] / pos[:, 3] + 1) * width / 2,
                     (pos[:, 1] / pos[:, 3] + 1) * height / 2], -1)


def test_alpha_is_half_minus_the_crossing_distance():
    """Every blended pair's alpha against the crossing computed in the window plane the
    way the derivation writes it (x = x_1 + (x_2 - x_1)(y_c - y_1)/(y_2 - y_1), for horizontal
    pairs; y likewise for vertical ones)."""
    pos, tri, colors = mesh_scene()
    rast, col = shade(pos, tri, colors)
    _, saved = antialias_forward(col, rast, pos, tri)
    p = saved.pairs
    assert len(p.tau) > 100
    xy = window_xy(pos, RES)
    a, b = xy[p.rows[:, 0]], xy[p.rows[:, 1]]
    cy = p.a_yx[:, 0] + 0.5
    cx = p.a_yx[:, 1] + 0.5
    horizontal = p.axis == 0
    x_cross = a[:, 0] + (b[:, 0] - a[:, 0]) * (cy - a[:, 1]) / (b[:, 1] - a[:, 1])
    y_cross = a[:, 1] + (b[:, 1] - a[:, 1]) * (cx - a[:, 0]) / (b[:, 0] - a[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.where(horizontal, x_cross - cx, y_cross - cy)
    np.testing.assert_allclose(p.tau, tau, atol=1e-9)
    assert ((p.tau > 0) & (p.tau < 1)).all()
    np.testing.assert_allclose(p.alpha, np.abs(0.5 - tau), atol=1e-9)
    # the pixel whose box holds the crossing is the one that blends
    at_a = (p.modified == p.a_yx).all(-1)
    assert (at_a == (p.tau < 0.5)).all()
    # and the edge is more across the pair's axis than along it
    d = np.abs(b - a)
    assert (np.where(horizontal, d[:, 1] >= d[:, 0], d[:, 0] >= d[:, 1])).all()


def coverage_area(pos, resolution):
    xy = window_xy(pos, resolution)
    (x0, y0), (x1, y1), (x2, y2) = xy
    return 0.5 * abs((x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0))


def test_antialiased_mask_follows_the_covered_area():
    """A constant-colour triangle over a black background: the antialiased image sums to
    its area (the aliased one only to the count of covered centres), and the gradient of
    that sum is the derivative of the area (the blend is box coverage)."""
    pos = f32([[-0.7, -0.6, 0.1, 1.0], [0.8, -0.3, 0.2, 1.2], [-0.1, 0.75, 0.3, 0.9]])
    tri = np.array([[0, 1, 2]], np.int32)
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=RES)
    mask = (rast[..., 3:4] > 0).astype(np.float64)
    out, saved = antialias_forward(mask, rast, pos, tri)
    area = coverage_area(pos, RES)
    assert abs(out.sum() - area) < 0.25 * abs(mask.sum() - area) + 0.05
    _, grad = antialias_backward(saved, np.ones_like(out))
    step = clip_px(pos, RES) * 1e-4
    true = np.zeros_like(pos)
    for v in range(3):
        for c in (0, 1, 3):
            d = np.zeros_like(pos)
            d[v, c] = step[v, c]
            true[v, c] = (coverage_area(pos + d, RES) - coverage_area(pos - d, RES)) / (2 * d[v, c])
    cols = [0, 1, 3]
    err = np.abs(grad[:, cols] - true[:, cols]) / np.abs(true[:, cols]).max()
    assert err.max() < 0.05, err


def test_shared_edges_are_not_blended_unless_the_vertices_are_split():
    """Two triangles of a quad in different colours: their shared edge is interior (no
    blend); with duplicated vertices it looks like a silhouette (nvdiffrast #84), and
    welding the duplicates restores the first result exactly."""
    pos = f32(window_to_clip([[10, 8], [50, 10], [45, 40], [12, 38]], RES))
    tri = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=RES)
    ids = rast[..., 3:4]
    col = np.where(ids == 1, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]) * (ids > 0)
    out, saved = antialias_forward(col, rast, pos, tri)
    edges = {frozenset(r) for r in saved.pairs.rows.tolist()}
    assert len(saved.pairs.tau) > 40 and frozenset((0, 2)) not in edges
    split_pos = pos[tri.ravel()]
    split_tri = np.arange(6).reshape(2, 3).astype(np.int32)
    split, ssaved = antialias_forward(col, rast, split_pos, split_tri)
    split_edges = [frozenset(r) for r in ssaved.pairs.rows.tolist()]
    shared = sum(e in (frozenset((0, 2)), frozenset((3, 5))) for e in split_edges)
    assert shared > 10 and np.abs(split - out).max() > 0.1
    welded, _ = antialias_forward(
        col, rast, split_pos, split_tri,
        aar.antialias_construct_topology_hash(split_tri, pos=split_pos))
    np.testing.assert_array_equal(welded, out)


def three_sided_scene():
    """A background pixel P = (4, 4) (centre 4.5, 4.5) with a triangle edge 0.1 px from its
    centre on three sides (left, right, below): each blend gives P alpha = 0.4."""
    res = (9, 9)
    left = window_to_clip([[4.4, -20], [4.4, 30], [-30, 5]], res, z=0.5)
    right = window_to_clip([[4.6, 30], [4.6, -20], [40, 5]], res, z=0.5)
    below = window_to_clip([[-30, 4.4], [-30, -30], [40, 4.4]], res, z=-0.5)
    pos = f32(np.concatenate([left, right, below]))
    return res, pos, np.arange(9).reshape(3, 3).astype(np.int32)


def test_convex_weights_keep_the_output_within_the_inputs_range():
    res, pos, tri = three_sided_scene()
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=res)
    assert rast[0, 4, 4, 3] == 0 and rast[0, 4, 3, 3] == 1 and rast[0, 4, 5, 3] == 2
    assert rast[0, 3, 4, 3] == 3
    col = np.where(rast[..., 3:4] > 0, 0.0, 1.0)          # black shapes, white background
    plain, saved = antialias_forward(col, rast, pos, tri, convex=False)
    p = saved.pairs
    at_p = (p.modified == [4, 4]).all(-1)
    np.testing.assert_allclose(np.sort(p.alpha[at_p]), [0.4, 0.4, 0.4], atol=1e-6)
    assert plain[0, 4, 4, 0] == pytest.approx(1 - 1.2, abs=1e-5)      # overshoots below 0
    convex, _ = antialias_forward(col, rast, pos, tri)
    assert convex.min() >= 0.0 and convex.max() <= 1.0
    assert convex[0, 4, 4, 0] == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- gradients


def central_differences(fn, pos, step, rows=None):
    """dL/dpos by central differences of fn(pos) -> L, per entry, z skipped."""
    out = np.zeros_like(pos)
    flat = pos.reshape(-1, 4)
    rows = range(len(flat)) if rows is None else rows
    for v in rows:
        for c in (0, 1, 3):
            d = np.zeros_like(flat)
            d[v, c] = step.reshape(-1, 4)[v, c]
            out.reshape(-1, 4)[v, c] = (fn((flat + d).reshape(pos.shape))
                                        - fn((flat - d).reshape(pos.shape))) / (2 * d[v, c])
    return out


@pytest.mark.parametrize("name", ["mesh", "soup", "behind", "instanced", "three_sided"])
def test_gradients_match_central_differences(name):
    """grad_pos (alpha as a function of the edge vertices, through the blend weights)
    against central differences of the float64 forward with rast frozen, steps of 1e-5 px;
    grad_color against differences in the colours. No pair is near a decision or the
    alpha kink (tau = 1/2), so the steps change no decision."""
    rng = np.random.default_rng(5)
    convex = True
    if name == "instanced":
        pos0, tri, colors = mesh_scene(level=1)
        pos1, _, _ = mesh_scene(level=1, eye=(-0.5, 0.2, 3.0))
        pos = np.stack([pos0, pos1])
        rast = np.concatenate([shade(p, tri, colors)[0] for p in pos])
        col = np.concatenate([shade(p, tri, colors)[1] for p in pos])
        res = RES
    elif name == "three_sided":
        res, pos, tri = three_sided_scene()
        (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=res)
        col = rng.uniform(0, 1, rast.shape[:3] + (2,))
    else:
        pos, tri, colors = SCENES[name]()
        rast, col = shade(pos, tri, colors)
        res = RES
    g = rng.normal(size=col.shape)
    out, saved = antialias_forward(col, rast, pos, tri, convex=convex)
    p = saved.pairs
    assert len(p.tau) > 3
    # pixels of ambiguous pairs (counted: a decision within the band, e.g. an edge through
    # a pixel centre of the icosphere) and of pairs crossing within 1e-3 px of the kink get
    # no upstream gradient, so that no step changes a decision that matters
    assert p.ambiguous.sum() <= 0.02 * p.ambiguous.size
    g[p.ambiguous] = 0.0
    kink = np.abs(p.tau - 0.5) < 1e-3
    for yx in (p.modified[kink], p.partner[kink]):
        g[p.batch[kink], yx[:, 0], yx[:, 1]] = 0.0
    assert kink.sum() < 0.05 * len(kink)
    if name == "three_sided":
        mod = p.modified[(p.modified == [4, 4]).all(-1)]
        assert len(mod) == 3                           # the normalised case is exercised
    grad_color, grad_pos = antialias_backward(saved, g)
    assert np.abs(grad_pos).max() > 0

    def loss(q):
        return float((antialias_forward(col, rast, q, tri, convex=convex)[0] * g).sum())

    rows = np.unique(p.rows)                           # the vertices that get a gradient
    numeric = central_differences(loss, pos, clip_px(pos, res) * 1e-5, rows)
    flat_a, flat_n = grad_pos.reshape(-1, 4), numeric.reshape(-1, 4)
    assert np.abs(np.delete(flat_a, rows, 0)).max(initial=0) == 0
    cols = [0, 1, 3]
    err = relative_error(flat_a[rows][:, cols], flat_n[rows][:, cols])
    assert np.abs(flat_n[rows][:, cols]).max() > 0
    print(f"{name}: {err.size} entries, max relative error {err.max():.1e}, "
          f"{p.ambiguous_pairs} ambiguous pairs, {kink.sum()} near the kink")
    assert err.max() < 1e-6, (name, err.max())
    # colours: the forward is linear in them
    e = rng.normal(size=col.shape)
    lin = (antialias_forward(col + e, rast, pos, tri, convex=convex)[0] * g).sum() \
        - (out * g).sum()
    assert lin == pytest.approx(float((grad_color * e).sum()), rel=1e-9)


def test_pos_gradient_boost_scales_the_position_gradient_only():
    pos, tri, colors = mesh_scene(level=1)
    rast, col = shade(pos, tri, colors)
    g = np.random.default_rng(2).normal(size=col.shape)
    _, s1 = antialias_forward(col, rast, pos, tri)
    _, s3 = antialias_forward(col, rast, pos, tri, pos_gradient_boost=3.0)
    c1, p1 = antialias_backward(s1, g)
    c3, p3 = antialias_backward(s3, g)
    np.testing.assert_array_equal(c1, c3)
    np.testing.assert_allclose(p3, 3 * p1, rtol=1e-15)


def test_w_nonpositive_vertices_stay_finite_and_blend_the_visible_edges():
    pos, tri, colors = behind_scene()
    rast, col = shade(pos, tri, colors)
    out, saved = antialias_forward(col, rast, pos, tri)
    assert np.isfinite(out).all()
    rows = np.unique(saved.pairs.rows)
    assert 2 in rows        # the edges to the vertex behind the eye are silhouettes too
    _, grad = antialias_backward(saved, np.ones_like(out))
    assert np.isfinite(grad).all() and np.abs(grad[2]).max() > 0


# --------------------------------------------------------------------------- bad input


def test_bad_input_raises_value_errors_naming_the_argument():
    pos, tri, colors = mesh_scene(level=1)
    rast, col = shade(pos, tri, colors)
    fwd = antialias_forward
    with pytest.raises(ValueError, match="color must have shape"):
        fwd(col[:, :-1], rast, pos, tri)
    with pytest.raises(ValueError, match="rast must have shape"):
        fwd(col, rast[..., :3], pos, tri)
    with pytest.raises(ValueError, match="color must be finite"):
        bad = col.copy()
        bad[0, 3, 3, 1] = np.nan
        fwd(bad, rast, pos, tri)
    with pytest.raises(ValueError, match="pos has a batch of 2"):
        fwd(col, rast, np.stack([pos, pos]), tri)
    with pytest.raises(ValueError, match="pos must have shape"):
        fwd(col, rast, pos[:, :3], tri)
    with pytest.raises(ValueError, match="topology_hash was built for a different tri"):
        fwd(col, rast, pos, tri, aar.antialias_construct_topology_hash(tri[:-1]))
    with pytest.raises(ValueError, match="topology_hash must come from"):
        fwd(col, rast, pos, tri, {"edges": 3})
    with pytest.raises(ValueError, match="pos_gradient_boost must be a finite number"):
        fwd(col, rast, pos, tri, pos_gradient_boost=float("nan"))
    with pytest.raises(ValueError, match="pos_gradient_boost must be a finite number"):
        fwd(col, rast, pos, tri, pos_gradient_boost=True)
    with pytest.raises(ValueError, match="convex must be True or False"):
        fwd(col, rast, pos, tri, convex=1)
    with pytest.raises(ValueError, match="rast holds triangle id"):
        fwd(col, rast, pos, tri[:5])
    _, saved = fwd(col, rast, pos, tri)
    with pytest.raises(ValueError, match="grad_out must have shape"):
        antialias_backward(saved, col[..., :2])
    with pytest.raises(ValueError, match="tri must have an integer dtype"):
        aar.antialias_construct_topology_hash(tri.astype(float))
    with pytest.raises(ValueError, match="tri must have shape"):
        aar.antialias_construct_topology_hash(tri[:, :2])
    with pytest.raises(ValueError, match="tri must hold vertex indices >= 0"):
        aar.antialias_construct_topology_hash(tri - 1)
    with pytest.raises(ValueError, match="pos for welding must have shape"):
        aar.antialias_construct_topology_hash(tri, pos=pos[:3])


def test_bad_input_error_carries_the_argument_name():
    pos, tri, colors = mesh_scene(level=1)
    rast, col = shade(pos, tri, colors)
    cases = [
        ("color", lambda: antialias_forward(col[:, :-1], rast, pos, tri)),
        ("pos", lambda: antialias_forward(col, rast, np.stack([pos, pos]), tri)),
        ("topology_hash", lambda: antialias_forward(
            col, rast, pos, tri, aar.antialias_construct_topology_hash(tri[:-1]))),
        ("topology_hash", lambda: antialias_forward(col, rast, pos, tri, {"edges": 3})),
        ("pos_gradient_boost", lambda: antialias_forward(col, rast, pos, tri,
                                                         pos_gradient_boost=True)),
        ("convex", lambda: antialias_forward(col, rast, pos, tri, convex=1)),
        ("tri", lambda: aar.antialias_construct_topology_hash(tri[:, :2])),
        ("pos", lambda: aar.antialias_construct_topology_hash(tri, pos=pos[:3])),
    ]
    for argument, call in cases:
        with pytest.raises(ArgumentError) as info:
            call()
        assert info.value.argument == argument
