"""The differentiable rasterize on the GPU (glraster.diff.rasterize) against float64.

rast (u, v, z/w, id) and rast_db (du/dx, du/dy, dv/dx, dv/dy) are compared per pixel with
the float64 reference (glraster.diff.rasterize_reference) at the pixel centre, within
per-pixel bounds derived from the float32 error model (see :func:`bounds`); pixels whose
triangle ids differ are masked and counted, and must lie where the reference rasterizer
says the winner is ambiguous (edge band, depth tie). Batches equal separate calls bit for
bit; depth peeling's layers 2 and 3 equal the float64 peeler's layers.
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster import reference
from glraster.conformance.scenes import load_scene
from glraster.diff.ids import MAX_ID, decode_ids, encode_ids
from glraster.diff import rasterize as dr
from glraster.diff import rasterize_reference
from glraster.diff.ops import RASTERIZE, depth_peeler
from glraster.geometry import synthetic
from glraster.gpu import pipeline
from glraster.gpu.context import Context
from glraster.gpu.methods import error_model
from glraster.verify.tolerance import EPS32, value_tolerance

# A representative subset of the catalog (< 60 s on both backends): perspective,
# shared edges, closed meshes, slivers, sub-pixel triangles, guard band, near plane,
# w < 0, extreme w ratios, depth ties and interpenetration, a 10k soup, orthographic.
SCENES = ("basic_perspective_triangle", "grid_perspective_jitter", "perspective_floor",
          "icosphere", "torus", "ortho_box", "slivers", "subpixel_triangles", "guard_band",
          "near_plane_crossing", "behind_camera", "w_extreme_ratios", "depth_fighting",
          "depth_interpenetrating", "soup_10k")


# --------------------------------------------------------------------------- float64


def forward(pos, tri, res, *, ctx, **params):
    """(rast, rast_db, saved) of RASTERIZE on float32 pos: checked, then the GPU core."""
    (rast, db), saved = RASTERIZE.forward(np.asarray(pos, np.float32), tri=tri,
                                          resolution=res, ctx=ctx, **params)
    return rast, db, saved


def float64_forward(pos, tri, resolution, space="persp", ctx=None, tri_id=None):
    """The float64 forward of one item and the per-pixel bounds of the GPU's error.

    Values: glraster.diff.rasterize_reference (``rasterize_values`` at the winning triangles of
    ``glraster.reference.rasterize``, i.e. ``rasterize_forward``, or at ``tri_id`` (H, W)
    when given, e.g. a depth layer). The bounds (:func:`bounds`) are evaluated from the
    reference rasterizer's per-triangle geometry (adj(M), det(M)).

    Returns a dict: rast, rast_db (H, W, 4) float64; tri_id (H, W) int (-1 empty);
    ambiguous (H, W) bool (edge band or depth tie of the winner); tol_rast, tol_db
    (H, W, 4) float64.
    """
    ref = reference.rasterize(pos, tri, resolution, outputs=("tri_id",))
    ids = ref.tri_id if tri_id is None else np.asarray(tri_id)
    height, width = resolution
    rast, db = rasterize_reference.rasterize_values(pos, tri, ids[None], space=space)
    out = {"tri_id": ids, "ambiguous": ref.ambiguous, "rast": rast[0], "rast_db": db[0]}
    tol_rast = np.zeros((height, width, 4))
    tol_db = np.zeros((height, width, 4))
    m = ids >= 0
    if m.any():
        ts = ref.triangles
        py, px = np.nonzero(m)
        t = ids[m]
        s, a = reference.edge_values(ts, t, px.astype(np.float64), py.astype(np.float64))
        det = ts.det[t][:, None]
        gx, gy = a[..., 0] / det, a[..., 1] / det             # d s_i / dx, d s_i / dy
        clip = ts.clip[t]
        z, w = clip[..., 2], clip[..., 3]
        if space == "persp":
            b = s / s.sum(1, keepdims=True)
        else:
            b = s * w
        bx = np.stack([out["rast_db"][m][:, 0], out["rast_db"][m][:, 2]], 1)
        by = np.stack([out["rast_db"][m][:, 1], out["rast_db"][m][:, 3]], 1)
        tol_rast[m], tol_db[m] = bounds(ts, ids, m, s, gx, gy, z, w, b, bx, by, space,
                                        resolution, ctx)
    out["tol_rast"], out["tol_db"] = tol_rast, tol_db
    return out


def bounds(ts, tri_id, m, s, gx, gy, z, w, b, bx, by, space, resolution, ctx):
    """Per-pixel bounds on |GPU - float64| of rast and rast_db, (K, 4) each.

    The shader evaluates s_i (scaled by k = max |w|) compensated, from float64 records
    rounded to float32, so each s_i is about one rounding off (plus an eps32^2 tail), as in
    the "homogeneous" method. With unit = C eps32 (C = 4, ErrorModel.ulp_factor, which
    covers two roundings of 2^-24 per term with a margin of 2 or more):

    - u, v: the "homogeneous" method's own per-pixel persp (screen) bound
      (glraster.verify.tolerance.value_tolerance with its compensated ErrorModel);
    - z/w = sum_i (k s_i)(z_i / k): a rounding on each s_i, z_i / k, product and partial sum
      of the dot product: unit * 2 sum_i |s_i z_i|, plus the evaluation's eps32^2 tail
      sum_i |z_i| |grad s_i|_1 (W + H);
    - persp d b_i/dx = (g_i - b_i G) / S, G = sum_j g_j: the stored g_i round once, G and
      the product and difference a few times, and b_i carries its own bound tol_b_i:
      (unit (|g_i| + |b_i| sum_j |g_j|) + |G| tol_b_i) / |S| + unit |d b_i/dx| (the last
      term for the division by S, itself a few roundings off);
    - screen d (s_i w_i)/dx = (k g_i)(w_i / k): unit |g_i w_i|.
    The id channel is compared exactly.
    """
    model = error_model("homogeneous", ctx)
    unit = model.ulp_factor * EPS32
    height, width = resolution
    tol = value_tolerance(ts, tri_id, (space,), model)
    tol_b = getattr(tol, space)[m]
    tol_r = np.zeros((len(s), 4))
    tol_r[:, :2] = tol_b[:, :2]
    grad1 = np.abs(gx) + np.abs(gy)
    tol_r[:, 2] = unit * 2 * np.abs(s * z).sum(1) \
        + EPS32 ** 2 * (np.abs(z) * grad1).sum(1) * (width + height)
    tol_d = np.zeros((len(s), 4))
    for col, (g, d) in enumerate(((gx[:, :2], bx), (gy[:, :2], by))):
        if space == "persp":
            total = np.abs(s.sum(1, keepdims=True))
            g3 = gx if col == 0 else gy
            bound = (unit * (np.abs(g) + np.abs(b[:, :2]) * np.abs(g3).sum(1, keepdims=True))
                     + np.abs(g3.sum(1, keepdims=True)) * tol_b[:, :2]) / total + unit * np.abs(d)
        else:
            bound = unit * np.abs(g * w[:, :2])
        tol_d[:, col], tol_d[:, 2 + col] = bound[:, 0], bound[:, 1]
    return tol_r, tol_d


def compare(gpu_rast, gpu_db, want):
    """Errors of one GPU item against :func:`float64_forward`'s ``want``: a dict with the
    id mismatch count (and how many lie outside the ambiguous pixels), per-channel-group
    absolute errors on the pixels where both have the same triangle, and the worst
    error / bound ratio."""
    gpu_ids = decode_ids(gpu_rast[..., 3])
    same = (gpu_ids == want["tri_id"])
    differ = ~same
    valid = same & (want["tri_id"] >= 0)
    err_r = np.abs(gpu_rast.astype(np.float64) - want["rast"])[valid]
    out = {"id_mismatch": int(differ.sum()),
           "id_mismatch_unambiguous": int((differ & ~want["ambiguous"]).sum()),
           "pixels": int(valid.sum()),
           "empty_nonzero": int(np.count_nonzero(gpu_rast[gpu_ids < 0]))}
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio_r = np.where(err_r[:, :3] > 0, err_r[:, :3] / want["tol_rast"][valid][:, :3], 0)
    out["id_exact"] = bool((err_r[:, 3] == 0).all())
    out["uv"], out["z"] = err_r[:, :2].ravel(), err_r[:, 2]
    out["ratio"] = float(ratio_r.max()) if ratio_r.size else 0.0
    if gpu_db is not None:
        err_d = np.abs(gpu_db.astype(np.float64) - want["rast_db"])[valid]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio_d = np.where(err_d > 0, err_d / want["tol_db"][valid], 0)
        out["db"] = err_d.ravel()
        out["db_rel"] = (err_d / np.maximum(np.abs(want["rast_db"][valid]), 1e-30)).ravel()
        out["ratio_db"] = float(ratio_d.max()) if ratio_d.size else 0.0
        out["empty_nonzero"] += int(np.count_nonzero(gpu_db[gpu_ids < 0]))
    return out


def _scene(name):
    s = load_scene(name)
    return s.pos, s.tri, s.resolution


# --------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize("name", SCENES)
def test_rast_and_rast_db_match_float64_within_their_bounds(ctx, name):
    """Ids exact wherever the winner is not ambiguous; values within :func:`bounds`;
    empty pixels all zero."""
    pos, tri, res = _scene(name)
    rast, db, saved = forward(pos, tri, res, ctx=ctx)
    assert rast.shape == db.shape == (1, *res, 4) and rast.dtype == db.dtype == np.float32
    got = compare(rast[0], db[0], float64_forward(pos, tri, res, ctx=ctx))
    assert got["pixels"] > 0
    assert got["id_mismatch_unambiguous"] == 0, got["id_mismatch_unambiguous"]
    assert got["id_exact"] and got["empty_nonzero"] == 0
    assert got["ratio"] <= 1.0, f"{name}: rast error / bound {got['ratio']:.3g}"
    assert got["ratio_db"] <= 1.0, f"{name}: rast_db error / bound {got['ratio_db']:.3g}"
    assert saved.rast is rast and saved.space == "persp" and saved.ranges is None


@pytest.mark.parametrize("name", ("basic_perspective_triangle", "torus", "w_extreme_ratios",
                                  "near_plane_crossing"))
def test_screen_space_matches_float64_within_its_bounds(ctx, name):
    """space="screen": u, v are the window-space barycentrics s_i w_i, rast_db their
    constant gradients; z/w and ids as in persp."""
    pos, tri, res = _scene(name)
    rast, db, saved = forward(pos, tri, res, ctx=ctx, space="screen")
    got = compare(rast[0], db[0], float64_forward(pos, tri, res, "screen", ctx=ctx))
    assert got["id_mismatch_unambiguous"] == 0
    assert got["ratio"] <= 1.0 and got["ratio_db"] <= 1.0, (got["ratio"], got["ratio_db"])
    assert saved.space == "screen"


def test_compensated_barycentrics_stay_within_a_few_ulps_on_well_shaped_triangles(ctx):
    """On 300 random triangles (vertices in the viewport, w in [0.2, 20]) u, v and z/w are
    within 4 float32 ulps of 1 (the compensated evaluation rounds about once); rast_db
    within 1e-5 relative to the largest derivative of the image (a plain float32 closed
    form: a handful of roundings on values of that size)."""
    pos, tri = synthetic.random_soup(300, seed=11)
    res = (128, 160)
    rast, db, _ = forward(pos, tri, res, ctx=ctx)
    want = float64_forward(pos, tri, res, ctx=ctx)
    got = compare(rast[0], db[0], want)
    assert got["uv"].max() <= 4 * EPS32 and got["z"].max() <= 4 * EPS32
    assert got["db"].max() <= 1e-5 * np.abs(want["rast_db"]).max()


def test_grad_db_false_returns_the_same_rast_and_no_rast_db(ctx):
    pos, tri, res = _scene("torus")
    rast, db, _ = forward(pos, tri, res, ctx=ctx)
    rast2, db2, _ = forward(pos, tri, res, ctx=ctx, grad_db=False)
    assert db2.shape == rast.shape[:3] + (0,) and db.shape == rast.shape
    np.testing.assert_array_equal(rast2, rast)


# --------------------------------------------------------------------------- ids


def test_id_encoding_is_exact_and_monotone_above_2_24():
    """encode_ids / decode_ids on ids around 2^24 and up to the largest finite
    encoding, without rendering 16M triangles."""
    index = np.array([0, 1, 2**24 - 2, 2**24 - 1, 2**24, 2**24 + 1, 2**25, 2**29, 123456789,
                      MAX_ID - 1])
    values = encode_ids(index)
    assert values.dtype == np.float32
    np.testing.assert_array_equal(decode_ids(values), index)
    order = np.argsort(index)
    assert (np.diff(values[order].astype(np.float64)) > 0).all()
    assert values[2] == 2.0**24 - 1 and values[3] == 2.0**24       # the value itself
    assert values[4].view(np.uint32) == 0x4A800000 + 2**24 + 1     # the bit pattern


def test_shader_encodes_ids_beyond_2_24_as_layout_does(ctx):
    """The resolve pass's encode_id, driven with an item whose first triangle has a large
    index (the id_base uniform the range mode sets), writes encode_ids's bits."""
    pos, tri = synthetic.random_soup(40, seed=2)
    res = (64, 64)
    job = dr._Forward(np.asarray(pos, np.float32), np.asarray(tri, np.int32), res, None, False,
                      "persp", ctx)
    for first in (2**24 - 20, 2**24 + 5, 2**27 + 3, 700_000_000):
        p, t, kept, _ = job._items[0]
        job._items[0] = (p, t, kept, first)
        rast, rast_db = job.new_outputs()
        job.draw(0, rast, rast_db)
        values = rast[0]
        plain, _, _ = forward(pos, tri, res, ctx=ctx, grad_db=False)
        index = decode_ids(plain[0, ..., 3])
        want = np.where(index >= 0, encode_ids(np.where(index >= 0, index + first, 0)), 0)
        np.testing.assert_array_equal(values[..., 3].view(np.uint32),
                                      want.astype(np.float32).view(np.uint32))
        np.testing.assert_array_equal(values[..., :3], plain[0, ..., :3])


# --------------------------------------------------------------------------- batches


def test_instanced_batch_equals_separate_calls(ctx):
    """pos (B, V, 4): item b is bit for bit forward(pos[b], tri)."""
    base, tri, res = _scene("icosphere")
    rng = np.random.default_rng(0)
    pos = np.stack([base * np.float32(s) + rng.normal(0, 0.05, base.shape).astype(np.float32)
                    * [1, 1, 0, 0] for s in (1.0, 0.7, 1.3)]).astype(np.float32)
    rast, db, saved = forward(pos, tri, res, ctx=ctx)
    assert rast.shape == (3, *res, 4) and saved.pos.shape == pos.shape
    for b in range(3):
        r1, d1, _ = forward(pos[b], tri, res, ctx=ctx)
        np.testing.assert_array_equal(rast[b], r1[0])
        np.testing.assert_array_equal(db[b], d1[0])


def test_range_batch_equals_separate_calls_with_ids_into_the_whole_tri(ctx):
    """ranges (B, 2): item b is forward(pos, tri[first:first + count]) with ids offset by
    first; an empty range gives an empty image."""
    pos, tri, res = _scene("soup_10k")
    ranges = np.array([[0, 300], [300, 4000], [9000, 1000], [5000, 0]])
    rast, db, saved = forward(pos, tri, res, ctx=ctx, ranges=ranges)
    assert rast.shape == (4, *res, 4)
    np.testing.assert_array_equal(saved.ranges, ranges)
    for b, (first, count) in enumerate(ranges):
        r1, d1, _ = forward(pos, tri[first:first + count], res, ctx=ctx)
        ids = decode_ids(r1[0, ..., 3])
        np.testing.assert_array_equal(decode_ids(rast[b, ..., 3]),
                                      np.where(ids >= 0, ids + first, -1))
        np.testing.assert_array_equal(rast[b, ..., :3], r1[0, ..., :3])
        np.testing.assert_array_equal(db[b], d1[0])
    assert not rast[3].any() and not db[3].any()


@pytest.mark.parametrize("small, sampled", [(False, False), (True, False), (False, True)])
def test_host_culling_changes_no_bit(ctx, monkeypatch, small, sampled):
    """An item whose triangles are half off-screen is drawn culled (ids remapped by the
    resolve pass), one with few dropped is drawn whole: both equal the unculled draw, also
    as small images resolved by one dispatch together, and each equals its own call.
    ``sampled``: the cull decided on a sample of the triangles first (as for large meshes)."""
    minimum = dr.CULL_MIN_TRIANGLES
    if sampled:
        monkeypatch.setattr(dr, "CULL_SAMPLE_TRIANGLES", minimum)
    pos, tri, res = _scene("icosphere")
    if small:
        res = (40, 56)
    pos = np.asarray(pos, np.float32)
    tri = np.asarray(tri, np.int32)
    shifted = pos.copy()
    shifted[:, 0] += 0.8 * shifted[:, 3]
    batch = np.stack([pos, shifted])
    kept = [len(dr._Forward(batch, tri, res, None, True, "persp", ctx)._items[b][1])
            for b in range(2)]
    assert kept[0] > 0.75 * len(tri) and kept[1] < 0.75 * len(tri)
    culled = forward(batch, tri, res, ctx=ctx)[:2]
    monkeypatch.setattr(dr, "CULL_MIN_TRIANGLES", len(tri) + 1)
    whole = forward(batch, tri, res, ctx=ctx)[:2]
    assert (culled[0][1, ..., 3] > 0).any()
    for a, b in zip(culled, whole):
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))
    monkeypatch.setattr(dr, "CULL_MIN_TRIANGLES", minimum)
    for b in range(2):
        alone = forward(batch[b], tri, res, ctx=ctx)[:2]
        for a, one in zip(culled, alone):
            np.testing.assert_array_equal(a[b].view(np.uint32), one[0].view(np.uint32))


def test_outputs_split_over_storage_blocks_are_the_same_bits(ctx, monkeypatch):
    """Record textures of 256 records and a driver storage block limit below the records
    and the output rows: the resolve pass runs per texture of records and per band of
    rows, the peeler's raster pass per batch of records, and every layer is bit for bit
    the one-block result."""
    pos, tri, res = _scene("icosphere")
    pos = np.asarray(pos, np.float32)
    tri = np.asarray(tri, np.int32)
    whole = [forward(pos, tri, res, ctx=ctx, space=space)[:2] for space in ("persp", "screen")]
    layers = peel(pos, tri, res, 2, ctx)
    limit = max(pos.nbytes, 16 * res[1] * 7)  # bands of 7 rows or so
    assert limit < len(tri) * dr.RECORD_STRIDE * 4 // 2 and limit < 16 * res[1] * res[0] // 2
    monkeypatch.setattr(ctx, "max_storage_block_size", limit)
    monkeypatch.setattr(dr, "RECORDS_PER_ROW", 4)
    monkeypatch.setattr(dr, "RECORD_TEXTURE_ROWS", 64)
    assert len(tri) > 3 * 4 * 64
    for space, (rast, db) in zip(("persp", "screen"), whole):
        split_rast, split_db, _ = forward(pos, tri, res, ctx=ctx, space=space)
        assert (rast[..., 3] > 0).any()
        np.testing.assert_array_equal(split_rast.view(np.uint32), rast.view(np.uint32))
        np.testing.assert_array_equal(split_db.view(np.uint32), db.view(np.uint32))
    for (rast, db, _), (split_rast, split_db, _) in zip(layers, peel(pos, tri, res, 2, ctx)):
        np.testing.assert_array_equal(split_rast.view(np.uint32), rast.view(np.uint32))
        np.testing.assert_array_equal(split_db.view(np.uint32), db.view(np.uint32))


# --------------------------------------------------------------------------- depth peeling


def peel(pos, tri, res, layers, ctx=None):
    """The first ``layers`` (rast, rast_db, saved) of the depth peeler of pos' dtype."""
    inputs, params = RASTERIZE.check(pos, tri=tri, resolution=res, ctx=ctx)
    with depth_peeler(*inputs, **params) as peeler:
        return [(*outputs, saved) for outputs, saved in
                (peeler.rasterize_next_layer() for _ in range(layers))]


def _peel_ambiguous(pos, tri, res, layers, tie=1e-5):
    """(H, W) bool: pixels where the float32 GPU and the float64 reference may order the
    first ``layers`` surfaces differently: two of the nearest ``layers`` + 1 surfaces within
    ``tie`` in z/w (the GPU compares float32 z/w, a few 1e-7 off), or a covering triangle's
    coverage is ambiguous (edge band). From each triangle rasterized alone."""
    zs, ambiguous = [], np.zeros(res, bool)
    for t in range(len(tri)):
        one = reference.rasterize(pos, tri[t:t + 1], res, outputs=("depth", "tri_id"))
        zs.append(np.where(one.mask, 2 * one.depth - 1, np.inf))
        ambiguous |= one.edge_band
    zs = np.sort(np.array(zs), axis=0)[:layers + 1]
    with np.errstate(invalid="ignore"):                  # inf - inf past the last surface
        ambiguous |= (np.abs(np.diff(zs, axis=0)) <= tie).any(0)
    return ambiguous


def test_depth_peel_layers_match_the_float64_layers(ctx):
    """Layer 1 equals forward(); layers 2 and 3 keep per pixel the nearest surface strictly
    behind the previous one, as the float64 peeler (glraster.diff.rasterize_reference)
    does: ids equal on every pixel where the surfaces are not within 1e-5 in z/w (masked
    and counted), values within the bounds of the single-layer test."""
    pos, tri = synthetic.random_soup(24, seed=7, w_range=(0.5, 4.0))
    res = (96, 128)
    want_layers = peel(np.asarray(pos, np.float64), tri, res, 3)
    ambiguous = _peel_ambiguous(pos, tri, res, 3)
    layers = peel(np.asarray(pos, np.float32), tri, res, 3, ctx)
    first, _, _ = forward(pos, tri, res, ctx=ctx)
    np.testing.assert_array_equal(layers[0][0], first)
    assert ambiguous.mean() < 0.01
    for k, ((rast, db, saved), (want_rast, _, _)) in enumerate(zip(layers, want_layers)):
        gpu_ids = decode_ids(rast[0, ..., 3])
        want_ids = decode_ids(want_rast[0, ..., 3])
        differ = (gpu_ids != want_ids) & ~ambiguous
        assert not differ.any(), f"layer {k + 1}: {differ.sum()} pixels with other ids"
        assert (gpu_ids >= 0).sum() > 500, "the scene must overlap in every layer"
        want = float64_forward(pos, tri, res, ctx=ctx, tri_id=np.where(gpu_ids == want_ids,
                                                                       gpu_ids, -1))
        np.testing.assert_array_equal(want["rast"][..., :3][want["tri_id"] >= 0],
                                      want_rast[0][..., :3][want["tri_id"] >= 0])
        got = compare(rast[0], db[0], want)
        assert got["ratio"] <= 1.0 and got["ratio_db"] <= 1.0, (k, got["ratio"], got["ratio_db"])


def test_depth_peeler_empties_and_batches(ctx):
    """A pixel empty in a layer stays empty; instanced batches peel per item; the peeler
    frees its texture."""
    pos, tri = synthetic.random_soup(12, seed=5)
    res = (48, 64)
    batch = np.stack([pos, pos[:, [1, 0, 2, 3]]])
    with dr.DepthPeeler(batch.astype(np.float32), tri=tri.astype(np.int32), resolution=res,
                        ranges=None, ctx=ctx) as peeler:
        prev = None
        for _ in range(4):
            (rast, _), _ = peeler.rasterize_next_layer()
            if prev is not None:
                assert not (rast[..., 3] != 0)[prev[..., 3] == 0].any()
            prev = rast
        for b in range(2):
            single = peel(batch[b].astype(np.float32), tri, res, 4, ctx)[-1][0]
            np.testing.assert_array_equal(single[0], rast[b])
    assert peeler._texture is None


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("kwargs, match", [
    ({"pos": np.zeros((3, 3))}, r"pos must have shape"),
    ({"pos": np.zeros((0, 3, 4))}, r"pos must have a batch"),
    ({"pos": np.full((3, 4), np.nan)}, r"pos must be finite"),
    ({"tri": np.array([[0, 1, 5]])}, r"tri index 5 is out of range"),
    ({"tri": np.zeros((2, 2), int)}, r"tri must have shape"),
    ({"resolution": (0, 8)}, r"resolution height"),
    ({"ranges": np.array([[0, 2]])}, r"ranges row 0"),
    ({"ranges": np.array([[-1, 1]])}, r"ranges row 0"),
    ({"ranges": np.array([0, 1])}, r"ranges must have shape"),
    ({"space": "clip"}, r"space must be one of"),
    ({"grad_db": "yes"}, r"grad_db must be True or False"),
])
def test_bad_input_raises_value_error_naming_the_argument(ctx, kwargs, match):
    args = {"pos": np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]], np.float32),
            "tri": np.array([[0, 1, 2]]), "resolution": (8, 8)}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        RASTERIZE.forward(args.pop("pos"), ctx=ctx, **args)


def test_resolution_above_the_drivers_texture_limit_is_refused(ctx):
    """The one check the GPU core makes itself: the driver's limit, which the op's check
    (no context) cannot know."""
    pos = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]], np.float32)
    with pytest.raises(ValueError, match="resolution"):
        RASTERIZE.forward(pos, tri=[[0, 1, 2]], resolution=(8, ctx.max_texture_size + 1),
                          ctx=ctx)


def test_needs_gl45_and_says_so_on_a_gl33_context(gl_backend):
    """On a 3.3 context the differentiable rasterize names the version it needs instead of
    failing in the shader compiler."""
    ctx = Context(backend=gl_backend, max_gl=33)
    try:
        pos = np.array([[-0.5, -0.5, 0, 1], [0.5, -0.5, 0, 1], [0, 0.5, 0, 1]], np.float32)
        with pytest.raises(ValueError, match=r"glraster.diff.rasterize needs OpenGL 4.5"):
            RASTERIZE.forward(pos, tri=[[0, 1, 2]], resolution=(8, 8), ctx=ctx)
    finally:
        ctx.release()
