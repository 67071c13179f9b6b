"""The float64 reference cores of rasterize, interpolate and depth peeling
(glraster.diff.rasterize_reference, glraster.diff.interpolate_reference), called through
their ops (glraster.diff.ops: checked once, then the core float64 selects): closed forms
against the glraster reference rasterizer, and every analytic derivative and backward pass
against central differences of the float64 forward. No GL.

Finite differences: four-point central differences (Richardson, error O(h^4)) of the closed
forms with the triangle ids frozen (``rasterize_values`` at the same pixels with the same
ids, as the backward assumes). The relative error of an entry is |analytic - numeric| /
max(|numeric|, 1e-3 max|numeric|) (the floor keeps entries that cancel to ~0 from dividing
by nothing); every test asserts max <= 1e-6, far above the ~1e-10 the differences reach
and far below any mistake in a derivative (which shows as O(1)). One test re-rasterizes
(coverage not frozen) with the upstream gradient on pixels at least 1 px inside their
triangle, to show that frozen coverage is what the real forward does there.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from glraster import reference as gref
from glraster.diff import interpolate_reference, rasterize_reference
from glraster.diff.ids import MAX_ID, decode_ids, encode_ids
from glraster.diff.ops import INTERPOLATE, RASTERIZE, depth_peeler
from glraster.diff.rasterize_reference import rasterize_values

RES = (24, 32)                       # (H, W): small, every test well under a second
TOL = 1e-6                           # relative error bound of the brief (see module doc)
# difference steps: the four-point truncation error falls as h^4 and reaches ~1e-7 at 4x
# these on the sliver and the w < 0 triangle of the random scene; here it is ~1e-10
H_PIXEL = 2.5e-3                     # window pixels
H_POS = 2.5e-4                       # clip-space units

# float32-representable positions, so that the glraster reference (which rasterizes the
# float32 positions a GPU sees) and the float64 closed forms see the same triangles
MESH_POS = np.array([
    [-0.75, -0.625, 0.125, 1.0],
    [0.8125, -0.5, 0.25, 2.0],
    [0.125, 0.875, -0.25, 1.5],
    [-0.875, 0.75, 0.5, 1.25],
    [0.625, 0.625, 0.0, 0.75],
], np.float64)
MESH_TRI = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])

# three overlapping triangles at increasing depth (z_ndc -0.5, 0, 0.5), drawn far to near
PEEL_POS = np.array([
    [-0.9, -0.9, 0.5, 1.0], [0.7, -0.8, 0.5, 1.0], [-0.1, 0.9, 0.5, 1.0],     # far
    [-0.6, -0.7, 0.0, 1.5], [1.2, -0.3, 0.0, 1.5], [0.0, 1.2, 0.0, 1.5],      # middle
    [-0.9, -0.2, -0.75, 1.5], [0.8, -0.9, -0.3, 0.6], [0.5, 0.9, -0.6, 1.2],  # near
], np.float32).astype(np.float64)
PEEL_TRI = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])


def instanced_pos():
    """(2, V, 4): the mesh and a moved copy (perspective changed)."""
    other = MESH_POS.copy()
    other[:, 0] += 0.125
    other[:, 3] *= np.array([1.0, 0.5, 1.5, 1.0, 2.0])
    other[:, :3] *= np.array([1.0, 0.5, 1.5, 1.0, 2.0])[:, None]
    return np.stack([MESH_POS, other])


def random_pos():
    """(27, 4): 8 random triangles (w in [0.5, 4], overlapping) and one crossing the near
    plane (a vertex behind the eye, w < 0), float32-exact."""
    rng = np.random.default_rng(11)
    ndc, w = rng.uniform(-1, 1, (24, 2)), rng.uniform(0.5, 4, 24)
    pos = np.c_[ndc * w[:, None], rng.uniform(-0.9, 0.9, 24) * w, w]
    behind = [[-0.5, -0.5, 0.0, 1.0], [0.6, -0.3, 0.2, 1.2], [0.1, 0.3, -0.9, -0.4]]
    return np.r_[pos, behind].astype(np.float32).astype(np.float64)


# name -> (pos, tri, ranges): plain (B = 1), instanced (B = 2), range mode (B = 2, the
# ranges overlap each other; ids index the whole tri), random (B = 1, depth test, w < 0)
BATCHES = {
    "plain": (MESH_POS, MESH_TRI, None),
    "random": (random_pos(), np.arange(27).reshape(9, 3), None),
    "instanced": (instanced_pos(), MESH_TRI, None),
    "ranges": (np.concatenate([MESH_POS, PEEL_POS]),
               np.concatenate([MESH_TRI, PEEL_TRI + len(MESH_POS)]),
               np.array([[0, 3], [2, 4]])),
}


def rel_error(analytic, numeric):
    """Per-entry relative error (module doc), flattened."""
    analytic, numeric = np.ravel(analytic), np.ravel(numeric)
    floor = 1e-3 * np.abs(numeric).max()
    assert floor > 0, "numeric derivative is all zero: nothing was tested"
    return np.abs(analytic - numeric) / np.maximum(np.abs(numeric), floor)


def four_point(f, h):
    """d/dt f(t) at t = 0 by four-point central differences; f returns an array."""
    return (8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h)


def gradient(f, x, h):
    """Four-point differences of the scalar f with respect to every entry of x."""
    out = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        def shifted(t, i=i):
            y = x.copy()
            y[i] += t
            return f(y)
        out[i] = four_point(shifted, h)
    return out


def covered(rast):
    return rast[..., 3] > 0


def interior(tri_id):
    """Pixels whose 8 neighbours hold the same triangle: >= ~1 px inside an edge."""
    pad = np.pad(tri_id, ((0, 0), (1, 1), (1, 1)), constant_values=-2)
    same = tri_id >= 0
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            same &= pad[:, dy:dy + tri_id.shape[1], dx:dx + tri_id.shape[2]] == tri_id
    return same


# --------------------------------------------------------------------------- the cores


def rasterize(pos, tri, res, **params):
    """(rast, rast_db, saved) of RASTERIZE (float64 pos: checked, then the reference)."""
    (rast, db), saved = RASTERIZE.forward(pos, tri=tri, resolution=res, **params)
    return rast, db, saved


def rasterize_backward(saved, grad_rast, grad_db=None):
    (grad_pos,) = rasterize_reference.backward(saved, grad_rast, grad_db)
    return grad_pos


def interpolate(attr, rast, tri, rast_db=None, diff_attrs=None):
    """(out, out_da, saved) of INTERPOLATE (float64 attr)."""
    (out, out_da), saved = INTERPOLATE.forward(attr, rast, rast_db, tri=tri,
                                               diff_attrs=diff_attrs)
    return out, out_da, saved


def interpolate_backward(saved, grad_out, grad_out_da=None, needs=None):
    return interpolate_reference.backward(saved, grad_out, grad_out_da, needs=needs)


def peel(pos, tri, res, layers, ranges=None, space="persp"):
    """The first ``layers`` (rast, rast_db, saved) of the float64 depth peeler."""
    inputs, params = RASTERIZE.check(np.asarray(pos, np.float64), tri=tri, resolution=res,
                                     ranges=ranges, space=space)
    with depth_peeler(*inputs, **params) as peeler:
        return [(*outputs, saved) for outputs, saved in
                (peeler.rasterize_next_layer() for _ in range(layers))]


def test_float64_selects_the_reference_cores():
    assert RASTERIZE.core(np.float64) is rasterize_reference
    assert INTERPOLATE.core(np.float64) is interpolate_reference


# --------------------------------------------------------------------------- forward


@pytest.mark.parametrize("batch", BATCHES)
def test_rast_matches_the_glraster_reference_per_batch(batch):
    # The same triangles (float32-exact positions): u, v = persp b0, b1 (or screen), z/w =
    # 2 depth - 1, ids = tri_id + 1, everything 0 on empty pixels. Tolerance 1e-12: two
    # float64 evaluations of one formula, in a different operation order.
    pos, tri, ranges = BATCHES[batch]
    for space, field in (("persp", "persp"), ("screen", "screen")):
        rast, db, saved = rasterize(pos, tri, RES, ranges=ranges, space=space)
        B = 2 if batch in ("instanced", "ranges") else 1
        assert rast.shape == db.shape == (B,) + RES + (4,)
        for b in range(B):
            if ranges is not None:
                first, count = ranges[b]
                ref = gref.rasterize(pos, tri[first:first + count], RES)
                ref_id = np.where(ref.mask, ref.tri_id + first, -1)
            else:
                ref = gref.rasterize(pos[b] if pos.ndim == 3 else pos, tri, RES)
                ref_id = ref.tri_id
            m = ref.mask
            assert m.sum() > 50
            np.testing.assert_array_equal(decode_ids(rast[b, ..., 3]), ref_id)
            np.testing.assert_array_equal(saved.tri_id[b], ref_id)
            np.testing.assert_allclose(rast[b][m][:, :2], getattr(ref, field)[m][:, :2],
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose(rast[b][m][:, 2], 2 * ref.depth[m] - 1, rtol=0,
                                       atol=1e-12)
            assert (rast[b][~m] == 0).all() and (db[b][~m] == 0).all()


def test_range_mode_ids_index_the_whole_tri():
    pos, tri, ranges = BATCHES["ranges"]
    rast, _, _ = rasterize(pos, tri, RES, ranges=ranges)
    ids = decode_ids(rast[..., 3])
    for b, (first, count) in enumerate(ranges):
        seen = set(np.unique(ids[b])) - {-1}
        assert seen and seen <= set(range(first, first + count)), (b, seen)


def test_screen_derivatives_are_constant_per_triangle():
    _, db, saved = rasterize(MESH_POS, MESH_TRI, RES, space="screen")
    for t in range(len(MESH_TRI)):
        m = saved.tri_id == t
        assert m.sum() > 10
        np.testing.assert_allclose(db[m], db[m][:1].repeat(m.sum(), 0), rtol=1e-12, atol=0)


# --------------------------------------------------------------------------- rast_db


@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("batch", BATCHES)
def test_rast_db_matches_differences_in_the_pixel_position(batch, space):
    pos, tri, ranges = BATCHES[batch]
    rast, db, saved = rasterize(pos, tri, RES, ranges=ranges, space=space)
    m = covered(rast)
    assert m.sum() > 100
    for axis, (cu, cv) in ((0, (0, 2)), (1, (1, 3))):
        def at(t, axis=axis):
            offset = (t, 0.0) if axis == 0 else (0.0, t)
            return rasterize_values(pos, tri, saved.tri_id, space=space, offset=offset)[0]
        numeric = four_point(at, H_PIXEL)
        for channel, uv in ((cu, 0), (cv, 1)):
            err = rel_error(db[..., channel][m], numeric[..., uv][m])
            assert err.max() <= TOL, (axis, channel, err.max())
        assert np.abs(db[m]).max() > 1e-3


# --------------------------------------------------------------------------- rasterize backward


@pytest.mark.parametrize("second_order", [False, True], ids=["rast", "rast+db"])
@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("batch", BATCHES)
def test_rasterize_backward_matches_differences(batch, space, second_order):
    pos, tri, ranges = BATCHES[batch]
    rng = np.random.default_rng(zlib.crc32(f"{batch} {space} {second_order}".encode()))
    rast, db, saved = rasterize(pos, tri, RES, ranges=ranges, space=space)
    grad_rast = rng.normal(size=rast.shape)              # channels 2, 3 must be ignored
    grad_db = rng.normal(size=db.shape) * 10 if second_order else None
    grad_pos = rasterize_backward(saved, grad_rast, grad_db)
    assert grad_pos.shape == np.shape(pos) and grad_pos.dtype == np.float64

    def loss(p):
        r, d = rasterize_values(p, tri, saved.tri_id, space=space)
        value = (r[..., :2] * grad_rast[..., :2]).sum()
        return value + ((d * grad_db).sum() if second_order else 0.0)

    numeric = gradient(loss, np.array(pos, np.float64), H_POS)
    assert np.abs(numeric[..., [0, 1, 3]]).min(axis=-1).max() > 0.1    # gradients non-zero
    assert (grad_pos[..., 2] == 0).all()
    np.testing.assert_allclose(numeric[..., 2], 0, atol=1e-9)           # dL/dz = 0
    err = rel_error(grad_pos[..., [0, 1, 3]], numeric[..., [0, 1, 3]])
    assert err.max() <= TOL, err.max()


def test_backward_matches_differences_of_the_real_forward_inside_triangles():
    # Coverage re-rasterized at every step (not frozen): with the upstream gradient on
    # pixels >= 1 px inside their triangle, the steps (<= 0.03 px) move no edge over them.
    pos, tri, _ = BATCHES["instanced"]
    rng = np.random.default_rng(3)
    rast, db, saved = rasterize(pos, tri, RES)
    inside = interior(saved.tri_id)[..., None]
    assert inside.sum() > 100
    grad_rast = rng.normal(size=rast.shape) * inside
    grad_db = rng.normal(size=db.shape) * inside
    grad_pos = rasterize_backward(saved, grad_rast, grad_db)

    def loss(p):
        r, d, _ = rasterize(p, tri, RES)
        return (r[..., :2] * grad_rast[..., :2]).sum() + (d * grad_db).sum()

    numeric = gradient(loss, pos.copy(), H_POS)
    err = rel_error(grad_pos[..., [0, 1, 3]], numeric[..., [0, 1, 3]])
    assert err.max() <= TOL, err.max()


def test_grad_of_empty_pixels_and_of_z_and_id_channels_is_ignored():
    rast, db, saved = rasterize(MESH_POS, MESH_TRI, RES)
    g = np.zeros(rast.shape)
    g[..., 2:] = 1.0                                     # z/w and id: no gradient
    g[~covered(rast)] = 7.0                              # empty pixels: frozen coverage
    grad_db = np.where(covered(rast)[..., None], 0.0, np.full(db.shape, 3.0))
    assert (rasterize_backward(saved, g, grad_db) == 0).all()


# --------------------------------------------------------------------------- interpolate


def test_interpolating_the_identity_gives_the_barycentrics():
    # attr = I (V, V): out[..., tri[t, j]] = b_j, and out_da = the b derivatives
    pos, tri, _ = BATCHES["instanced"]
    rast, db, saved = rasterize(pos, tri, RES)
    out, out_da, _ = interpolate(np.eye(len(MESH_POS)), rast, tri, db, "all")
    m = covered(rast)
    verts = tri[saved.tri_id[m]]
    rows = np.arange(m.sum())
    np.testing.assert_allclose(out[m][rows, verts[:, 0]], rast[m][:, 0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out[m][rows, verts[:, 1]], rast[m][:, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out[m].sum(-1), 1.0, rtol=0, atol=1e-14)
    da = out_da[m].reshape(-1, len(MESH_POS), 2)
    np.testing.assert_allclose(da[rows, verts[:, 0]], db[m][:, [0, 1]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(da[rows, verts[:, 1]], db[m][:, [2, 3]], rtol=0, atol=1e-15)
    assert (out[~m] == 0).all() and (out_da[~m] == 0).all()


@pytest.mark.parametrize("space", ["persp", "screen"])
def test_out_da_matches_differences_in_the_pixel_position(space):
    rng = np.random.default_rng(4)
    pos, tri, _ = BATCHES["instanced"]
    attr = rng.normal(size=(2, len(MESH_POS), 4))
    chosen = [3, 0, 3]                                   # order kept, repeats allowed
    rast, db, saved = rasterize(pos, tri, RES, space=space)
    _, out_da, _ = interpolate(attr, rast, tri, db, chosen)
    assert out_da.shape == (2,) + RES + (6,)
    m = covered(rast)
    for axis in (0, 1):
        def at(t, axis=axis):
            offset = (t, 0.0) if axis == 0 else (0.0, t)
            r, _ = rasterize_values(pos, tri, saved.tri_id, space=space, offset=offset)
            return interpolate(attr, r, tri)[0]
        numeric = four_point(at, H_PIXEL)
        for slot, k in enumerate(chosen):
            err = rel_error(out_da[..., 2 * slot + axis][m], numeric[..., k][m])
            assert err.max() <= TOL, (axis, k, err.max())


@pytest.mark.parametrize("attr_batch", [None, 1, 2], ids=["2d", "broadcast", "batched"])
def test_interpolate_backward_matches_differences(attr_batch):
    # the op alone: attr, rast (u, v) and rast_db as independent inputs
    rng = np.random.default_rng(5)
    pos, tri, _ = BATCHES["instanced"]
    rast, db, _ = rasterize(pos, tri, RES)
    shape = (len(MESH_POS), 3) if attr_batch is None else (attr_batch, len(MESH_POS), 3)
    attr = rng.normal(size=shape)
    chosen = [2, 0]
    out, out_da, saved = interpolate(attr, rast, tri, db, chosen)
    g_out = rng.normal(size=out.shape)
    g_da = rng.normal(size=out_da.shape)
    g_attr, g_rast, g_db = interpolate_backward(saved, g_out, g_da)
    assert g_attr.shape == attr.shape and g_rast.shape == rast.shape == g_db.shape
    assert (g_rast[..., 2:] == 0).all()

    def loss(a=attr, r=rast, d=db):
        o, oda, _ = interpolate(a, r, tri, d, chosen)
        return (o * g_out).sum() + (oda * g_da).sum()

    err = rel_error(g_attr, gradient(lambda a: loss(a=a), attr, 1e-3))
    assert err.max() <= TOL, err.max()
    m = covered(rast)
    # u, v and the db channels enter linearly: one difference per channel, all pixels at once
    # (each pixel's output depends only on its own rast values)
    for channel in (0, 1):
        def shifted(t, channel=channel):
            r = rast.copy()
            r[..., channel] += t * m
            return (interpolate(attr, r, tri, db, chosen)[0] * g_out).sum(-1) + (
                interpolate(attr, r, tri, db, chosen)[1] * g_da).sum(-1)
        err = rel_error(g_rast[..., channel][m], four_point(shifted, 1e-3)[m])
        assert err.max() <= TOL, (channel, err.max())
    for channel in range(4):
        def shifted(t, channel=channel):
            d = db.copy()
            d[..., channel] += t * m
            return (interpolate(attr, rast, tri, d, chosen)[1] * g_da).sum(-1)
        err = rel_error(g_db[..., channel][m], four_point(shifted, 1e-3)[m])
        assert err.max() <= TOL, (channel, err.max())


def test_interpolate_without_diff_attrs_returns_no_rast_db_gradient():
    rast, db, _ = rasterize(MESH_POS, MESH_TRI, RES)
    out, out_da, saved = interpolate(np.ones((len(MESH_POS), 2)), rast, MESH_TRI, db)
    assert out_da.shape == out.shape[:3] + (0,)
    g_attr, _, g_db = interpolate_backward(saved, np.ones(out.shape))
    assert g_db is None
    # sum over pixels of the constant-1 attribute: each pixel's barycentrics sum to 1
    np.testing.assert_allclose(g_attr.sum(0), covered(rast).sum(), rtol=1e-12)


@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("batch", ["instanced", "ranges"])
def test_rasterize_then_interpolate_chain_matches_differences(batch, space):
    # pos -> (rast, rast_db) -> (out, out_da): the second-order path end to end
    rng = np.random.default_rng(6)
    pos, tri, ranges = BATCHES[batch]
    attr = rng.normal(size=(np.shape(pos)[-2], 3))
    chosen = "all"
    rast, db, r_saved = rasterize(pos, tri, RES, ranges=ranges, space=space)
    out, out_da, i_saved = interpolate(attr, rast, tri, db, chosen)
    g_out, g_da = rng.normal(size=out.shape), rng.normal(size=out_da.shape)
    g_attr, g_rast, g_db = interpolate_backward(i_saved, g_out, g_da)
    g_pos = rasterize_backward(r_saved, g_rast, g_db)

    def loss(p, a):
        r, d = rasterize_values(p, tri, r_saved.tri_id, space=space)
        o, oda, _ = interpolate(a, r, tri, d, chosen)
        return (o * g_out).sum() + (oda * g_da).sum()

    numeric = gradient(lambda p: loss(p, attr), np.array(pos, np.float64), H_POS)
    err = rel_error(g_pos[..., [0, 1, 3]], numeric[..., [0, 1, 3]])
    assert err.max() <= TOL, err.max()
    err = rel_error(g_attr, gradient(lambda a: loss(pos, a), attr, 1e-3))
    assert err.max() <= TOL, err.max()


# --------------------------------------------------------------------------- depth peeling


def test_depth_peeling_layers_lie_strictly_behind_each_other():
    layers = [(rast, db) for rast, db, _ in peel(PEEL_POS, PEEL_TRI, RES, 4)]
    assert len(layers) == 4
    rast0, db0, _ = rasterize(PEEL_POS, PEEL_TRI, RES)
    np.testing.assert_array_equal(layers[0][0], rast0)   # layer 0 = the rasterizer
    np.testing.assert_array_equal(layers[0][1], db0)
    # how many triangles cover each pixel (each alone through the glraster reference)
    hits = sum(gref.rasterize(PEEL_POS, PEEL_TRI[t:t + 1], RES).mask.astype(int)
               for t in range(3))
    for k, (rast, db) in enumerate(layers):
        np.testing.assert_array_equal(covered(rast)[0], hits > k)
        assert (db[~covered(rast)] == 0).all()
    two = covered(layers[1][0])
    assert two.sum() > 30 and covered(layers[2][0]).sum() > 10
    assert not covered(layers[3][0]).any()
    for k in (1, 2):                                      # z/w strictly increases per layer
        m = covered(layers[k][0])
        assert (layers[k][0][..., 2][m] > layers[k - 1][0][..., 2][m]).all()
    # drawn far to near: layer 0 is the near triangle, layer 1 the middle, layer 2 the far
    ids1 = decode_ids(layers[1][0][..., 3])[two]
    assert set(np.unique(ids1)) == {0, 1}


def test_depth_peeling_layer_backward_matches_differences():
    rng = np.random.default_rng(7)
    pos, tri, ranges = BATCHES["ranges"]
    rast, db, saved = peel(pos, tri, RES, 2, ranges, space="persp")[1]
    assert covered(rast).sum() > 30
    np.testing.assert_array_equal(rasterize_values(pos, tri, saved.tri_id)[0], rast)
    grad_rast, grad_db = rng.normal(size=rast.shape), rng.normal(size=db.shape)
    grad_pos = rasterize_backward(saved, grad_rast, grad_db)

    def loss(p):
        r, d = rasterize_values(p, tri, saved.tri_id)
        return (r[..., :2] * grad_rast[..., :2]).sum() + (d * grad_db).sum()

    numeric = gradient(loss, pos.copy(), H_POS)
    err = rel_error(grad_pos[..., [0, 1, 3]], numeric[..., [0, 1, 3]])
    assert err.max() <= TOL, err.max()


# --------------------------------------------------------------------------- triangle ids


def test_ids_encode_as_floats_then_as_bit_patterns_monotone_and_exact():
    tri_id = np.array([-1, 0, 1, 2**24 - 2, 2**24 - 1, 2**24, 2**24 + 1, 10**8, 2**29,
                       MAX_ID - 1])
    enc = encode_ids(tri_id)
    assert enc.dtype == np.float32
    assert enc[0] == 0 and enc[1] == 1 and enc[4] == 2.0**24       # id = index + 1
    assert enc.view(np.uint32)[5] == 0x4A800000 + 2**24 + 1
    assert np.isfinite(enc).all() and (np.diff(enc) > 0).all()       # monotone as floats
    np.testing.assert_array_equal(decode_ids(enc), tri_id)
    np.testing.assert_array_equal(decode_ids(enc.astype(np.float64)), tri_id)
    with pytest.raises(ValueError, match="tri_id must be <"):
        encode_ids([MAX_ID])
    with pytest.raises(ValueError, match="rast id channel must hold encoded"):
        decode_ids(np.array([1.5]))


# --------------------------------------------------------------------------- bad input


def _rast():
    rast, db, saved = rasterize(MESH_POS, MESH_TRI, RES)
    return rast, db, saved


def _bad_cases():
    P, T = MESH_POS, MESH_TRI
    nan = P.copy()
    nan[1, 2] = np.nan
    rast, db, saved = _rast()
    bad_id = rast.copy()
    bad_id[0, 10, 10, 3] = 9.0
    frac_id = rast.copy()
    frac_id[0, 10, 10, 3] = 1.5
    attr = np.ones((len(P), 2))
    return [
        (lambda: rasterize(P[:, :3], T, RES), r"pos must have shape \(V, 4\)"),
        (lambda: rasterize(nan, T, RES), "pos must be finite, got NaN"),
        (lambda: rasterize(P.astype(str), T, RES), "pos must hold real numbers"),
        (lambda: rasterize(P, T + 3, RES), "tri index 7 is out of range"),
        (lambda: rasterize(P, T * 1.0, RES), "tri must have an integer dtype"),
        (lambda: rasterize(P, T, (0, 4)), "resolution height must be > 0"),
        (lambda: rasterize(P, T, RES, space="ndc"), "space must be one of"),
        (lambda: rasterize(P, T, RES, ranges=[[1, 3]]),
         r"ranges row 0 = \[1, 3\] reaches triangle 3, beyond tri's 3 triangles"),
        (lambda: rasterize(P, T, RES, ranges=[[0, 1], [-1, 1]]),
         "ranges row 1 must have first >= 0"),
        (lambda: rasterize(P, T, RES, ranges=[[0, 1, 2]]), "ranges must have shape"),
        (lambda: rasterize(P, T, RES, ranges=[[0.0, 1.0]]), "ranges must have an integer dtype"),
        (lambda: rasterize_values(P, T, saved.tri_id + 5), "tri_id must hold -1 or indices"),
        (lambda: interpolate(attr[None, None], rast, T), "attr must have shape"),
        (lambda: interpolate(np.ones((3, len(P), 2)), rast, T), "attr has a batch"),
        (lambda: interpolate(attr, rast, T, None, "all"), "diff_attrs needs rast_db"),
        (lambda: interpolate(attr, rast, T, db, [0, 2]), "diff_attrs index 2 is out of range"),
        (lambda: interpolate(attr, rast, T, db, "some"), "diff_attrs must be None"),
        (lambda: interpolate(attr, rast, T, db, [0.0]), "diff_attrs must hold integer"),
        (lambda: interpolate(attr, rast, T, db[..., :2], [0]), "rast_db must have shape"),
        (lambda: interpolate(attr, rast[0], T), r"rast must have shape \(B, H, W, 4\)"),
        (lambda: interpolate(attr, bad_id, T), "beyond tri's 3 triangles"),
        (lambda: interpolate(attr, frac_id, T), "rast channel 3"),
        (lambda: interpolate(attr, rast, T + 2), "tri index 6 is out of range"),
    ]


@pytest.mark.parametrize("case", range(len(_bad_cases())))
def test_bad_input_raises_value_error_naming_the_argument(case):
    call, message = _bad_cases()[case]
    with pytest.raises(ValueError, match=message):
        call()
