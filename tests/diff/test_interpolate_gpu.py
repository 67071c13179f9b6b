"""Interpolation on the GPU (glraster.diff.interpolate, called through INTERPOLATE: checked
once, then the core float32 selects) against float64.

The float64 closed forms are evaluated here in the running-error arithmetic of
test_rasterize_backward (:class:`Err`: value and a first-order bound m on the float32
evaluation of the same expression, |float32 - exact| <= u m) and checked against central
differences and against glraster.diff.interpolate_reference. Per-pixel outputs (out,
out_da, grad_rast, grad_rast_db) must lie within K u m of float64; grad_attr within the sum
of its pixels' bounds plus the float32 summation bound. The inputs (attr, rast, rast_db,
upstream gradients) are float32 numbers and exact.
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster import validate
from glraster.diff import buffer_views, compute, interpolate_reference
from glraster.diff import interpolate as ip
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from tests.diff.test_rasterize_backward import U32, Err, covered, random_soup

# every operation of Err counts one rounding; K leaves a margin for fma contraction
K = 2.0


def gpu_raster(ctx, pos, tri, resolution):
    (rast, rast_db), _ = RASTERIZE.forward(pos, tri=tri, resolution=resolution, ctx=ctx,
                                           grad_db=True)
    return rast, rast_db


def forward(attr, rast, tri, rast_db=None, diff_attrs=None, *, ctx):
    """(out, out_da, saved) of INTERPOLATE on float32 attr: the GPU core."""
    (out, out_da), saved = INTERPOLATE.forward(attr, rast, rast_db, tri=tri,
                                               diff_attrs=diff_attrs, ctx=ctx)
    return out, out_da, saved


def reference(attr, rast, tri, rast_db, diff_attrs, go, gda):
    """((out, out_da), (grad_attr, grad_rast, grad_rast_db)) of the float64 core."""
    f64 = [None if a is None else np.asarray(a, np.float64) for a in (attr, rast, rast_db)]
    outputs, saved = INTERPOLATE.forward(*f64, tri=tri, diff_attrs=diff_attrs)
    grads = interpolate_reference.backward(saved, np.asarray(go, np.float64),
                                           None if gda is None else gda.astype(np.float64))
    return outputs, grads


@pytest.fixture
def scene(ctx):
    pos, tri, res = random_soup(21, 40)
    rast, rast_db = gpu_raster(ctx, pos, tri, res)
    assert (rast[..., 3] > 0).sum() > 500, "the scene must cover pixels"
    rng = np.random.default_rng(22)
    attr = rng.normal(size=(len(pos), 5)).astype(np.float32)
    return attr, rast, rast_db, tri, rng


def closed_forms(attr, rast, rast_db, tri, diff, go, gda):
    """Err per covered pixel: out (A), out_da (2D), grad_rast (u, v), grad_db (4) and the
    three corners' grad_attr terms (3, A), mirroring the shaders' order of operations."""
    b, y, x, t = covered(rast, tri)
    attr3 = attr if attr.ndim == 3 else attr[None]
    ab = b if attr3.shape[0] > 1 else np.zeros_like(b)
    vert = tri[t].astype(np.int64)
    a = attr3[ab[:, None], vert].astype(np.float64)               # (N, 3, A)
    u, v = Err(rast[b, y, x, 0]), Err(rast[b, y, x, 1])
    w = 1.0 - u - v
    db = [Err(c) for c in rast_db[b, y, x].T] if rast_db is not None else None
    A = a.shape[2]
    out, gu, gv, corner = [], Err(0.0), Err(0.0), [[], [], []]
    slot = {k: j for j, k in enumerate(diff)}
    out_da = [None] * (2 * len(diff))
    gdb = [Err(0.0)] * 4
    for k in range(A):
        a0, a1, a2 = (Err(a[:, j, k]) for j in range(3))
        out.append(u * a0 + v * a1 + w * a2)
        d0, d1 = a0 - a2, a1 - a2
        g = Err(go[b, y, x, k])
        gu, gv = gu + g * d0, gv + g * d1
        c0 = c1 = Err(0.0)
        if k in slot:
            j = slot[k]
            out_da[2 * j] = d0 * db[0] + d1 * db[2]
            out_da[2 * j + 1] = d0 * db[1] + d1 * db[3]
            if gda is not None:
                gx, gy = Err(gda[b, y, x, 2 * j]), Err(gda[b, y, x, 2 * j + 1])
                gdb = [gdb[0] + gx * d0, gdb[1] + gy * d0, gdb[2] + gx * d1, gdb[3] + gy * d1]
                c0, c1 = gx * db[0] + gy * db[1], gx * db[2] + gy * db[3]
        corner[0].append(u * g + c0)
        corner[1].append(v * g + c1)
        corner[2].append(w * g - (c0 + c1))
    index = (ab[:, None] * attr3.shape[1] + vert)
    return (b, y, x), out, out_da, (gu, gv), gdb, corner, index


def stack(errs):
    return (np.stack([np.broadcast_to(e.v, errs[0].v.shape) for e in errs], -1),
            np.stack([np.broadcast_to(e.m, errs[0].v.shape) for e in errs], -1))


def within(got, errs, what):
    want, m = stack(errs)
    err = np.abs(got - want)
    ratio = err / np.maximum(U32 * m, 1e-300)
    assert (ratio <= K).all(), f"{what}: max |err| / (u m) = {ratio.max():.2f}"
    return want


@pytest.mark.parametrize("diff", [None, [3, 0], "all"])
def test_forward_within_running_error_bound(ctx, scene, diff):
    attr, rast, rast_db, tri, _ = scene
    out, out_da, _ = forward(attr, rast, tri, rast_db, diff, ctx=ctx)
    chosen = validate.diff_attrs(diff, attr.shape[1]) or ()
    px, o, oda, *_ = closed_forms(attr, rast, rast_db, tri, chosen, np.zeros_like(out), None)
    assert out.shape == rast.shape[:3] + (5,) and out.dtype == np.float32
    want = within(out[px], o, "out")
    assert np.abs(want).max() > 0
    covered_mask = np.zeros(rast.shape[:3], bool)
    covered_mask[px] = True
    assert not out[~covered_mask].any(), "empty pixels must be 0"
    if diff is None:
        assert out_da.shape == rast.shape[:3] + (0,)
    else:
        assert out_da.shape == rast.shape[:3] + (2 * len(chosen),)
        within(out_da[px], oda, "out_da")
        assert not out_da[~covered_mask].any()
    (o64, _da64), _ = reference(attr, rast, tri, rast_db, diff, out, None)
    np.testing.assert_allclose(want, o64[px], rtol=0, atol=1e-12)


@pytest.mark.parametrize("accumulate", compute.FIXED_POINT_ACCUMULATIONS)
@pytest.mark.parametrize("diff", [None, [4, 1], "all"])
def test_backward_within_bound_and_matches_reference(ctx, scene, diff, accumulate):
    """grad_rast, grad_rast_db per pixel within K u m; grad_attr per vertex within the
    sum of its pixels' bounds + (n - 1) u sum |c| (atomics) or n 2^-(k+1) (fixed point,
    k from an upper bound on the largest term), + u |sum|."""
    if accumulate == "atomic_float" and not compute.has_atomic_float(ctx):
        pytest.skip("the driver has no GL_NV_shader_atomic_float")
    attr, rast, rast_db, tri, rng = scene
    out, out_da, saved = forward(attr, rast, tri, rast_db, diff, ctx=ctx)
    go = rng.normal(size=out.shape).astype(np.float32)
    gda = None if diff is None else rng.normal(size=out_da.shape).astype(np.float32)
    grad_attr, grad_rast, grad_db = ip.backward(saved, go, gda, accumulate=accumulate)
    px, _, _, gr_uv, gdb, corner, index = closed_forms(attr, rast, rast_db, tri,
                                                       saved.diff_attrs, go, gda)
    within(grad_rast[px][:, :2], list(gr_uv), "grad_rast")
    assert not grad_rast[..., 2:].any()
    if diff is None:
        assert grad_db is None
    else:
        within(grad_db[px], gdb, "grad_rast_db")
    num = attr.shape[0]
    want = np.zeros((num, attr.shape[1]))
    bound = np.zeros_like(want)
    mag = np.zeros_like(want)
    for k in range(attr.shape[1]):
        vals = np.stack([corner[j][k].v for j in range(3)], 1)
        ms = np.stack([corner[j][k].m for j in range(3)], 1)
        want[:, k] = np.bincount(index.ravel(), vals.ravel(), num)
        bound[:, k] = np.bincount(index.ravel(), K * U32 * ms.ravel(), num)
        mag[:, k] = np.bincount(index.ravel(), np.abs(vals).ravel(), num)
    n = np.bincount(index.ravel(), minlength=num)[:, None]
    if accumulate == "fixed_point":
        largest = max((np.abs(corner[j][k].v) + K * U32 * corner[j][k].m).max()
                      for j in range(3) for k in range(attr.shape[1]))
        k = compute.fixed_point_exponent(largest, 3 * rast[..., 0].size)
        summation = n * 2.0 ** -(k + 1)
    else:
        summation = np.maximum(n - 1, 0) * U32 * (mag + bound)
    assert grad_attr.shape == attr.shape and np.abs(grad_attr).max() > 0
    assert (np.abs(grad_attr - want) <= bound + summation + U32 * np.abs(want)).all()
    _, r = reference(attr, rast, tri, rast_db, diff, go, gda)
    np.testing.assert_allclose(want, r[0], rtol=0, atol=1e-9 * np.abs(r[0]).max())


def test_closed_forms_match_central_differences(ctx, scene):
    """The float64 closed forms against central differences of the float64 forward (the
    Err values) in attr, u, v and rast_db of sample pixels: L is polynomial of degree 2
    in them, so central differences are exact up to rounding (1e-7 of the largest)."""
    attr, rast, rast_db, tri, rng = scene
    diff = (0, 2)
    px, _o, _oda, gr_uv, gdb, corner, index = closed_forms(
        attr, rast, rast_db, tri, diff, go := rng.normal(size=rast.shape[:3] + (5,)),
        gda := rng.normal(size=rast.shape[:3] + (4,)))

    def loss(attr_, rast_, db_):
        p, o_, oda_, *_ = closed_forms(attr_, rast_, db_, tri, diff, go, None)
        return sum((e.v * go[p + (k,)]).sum() for k, e in enumerate(o_)) + \
            sum((e.v * gda[p + (k,)]).sum() for k, e in enumerate(oda_))

    step = 1e-3
    a64, r64, d64 = attr.astype(np.float64), rast.astype(np.float64), rast_db.astype(np.float64)
    vtx = index[5, 0]
    for k in range(5):
        up, down = a64.copy(), a64.copy()
        up[vtx, k] += step
        down[vtx, k] -= step
        fd = (loss(up, r64, d64) - loss(down, r64, d64)) / (2 * step)
        terms = np.stack([corner[j][k].v for j in range(3)], 1)
        analytic = np.bincount(index.ravel(), terms.ravel(), len(attr))[vtx]
        assert abs(fd - analytic) <= 1e-7 * max(1.0, abs(analytic)), ("attr", k)
    for n in (0, 17, len(px[0]) - 1):
        where = tuple(c[n] for c in px)
        for c, grad in ((0, gr_uv[0].v[n]), (1, gr_uv[1].v[n])):
            up, down = r64.copy(), r64.copy()
            up[where + (c,)] += step
            down[where + (c,)] -= step
            fd = (loss(a64, up, d64) - loss(a64, down, d64)) / (2 * step)
            assert abs(fd - grad) <= 1e-7 * max(1.0, abs(grad)), ("rast", n, c)
        for c in range(4):
            up, down = d64.copy(), d64.copy()
            up[where + (c,)] += step
            down[where + (c,)] -= step
            fd = (loss(a64, r64, up) - loss(a64, r64, down)) / (2 * step)
            assert abs(fd - gdb[c].v[n]) <= 1e-7 * max(1.0, abs(gdb[c].v[n])), ("db", n, c)


def test_deterministic_is_bit_identical_over_three_runs(ctx, scene):
    attr, rast, rast_db, tri, rng = scene
    out, out_da, saved = forward(attr, rast, tri, rast_db, "all", ctx=ctx)
    go = rng.normal(size=out.shape).astype(np.float32)
    gda = rng.normal(size=out_da.shape).astype(np.float32)
    runs = [ip.backward(saved, go, gda, deterministic=True) for _ in range(3)]
    assert np.abs(runs[0][0]).max() > 0
    for other in runs[1:]:
        for x, y in zip(runs[0], other):
            assert np.array_equal(x.view(np.uint32), y.view(np.uint32))


def test_batched_and_broadcast_attributes(ctx, scene):
    """(B, V, A) attr: item b interpolates attr[b]; (V, A) attr over a batch of 2 rasters:
    grad_attr is the sum of the items' (deterministic: one rounding of each)."""
    attr, rast, _rast_db, tri, rng = scene
    rasts = np.concatenate([rast, rast[:, ::-1].copy()])
    attr2 = np.stack([attr, attr * np.float32(-2)])
    out, _, saved = forward(attr2, rasts, tri, ctx=ctx)
    for i in range(2):
        one, _, _ = forward(attr2[i], rasts[i:i + 1], tri, ctx=ctx)
        assert np.array_equal(out[i], one[0])
    go = rng.normal(size=out.shape).astype(np.float32)
    g2 = ip.backward(saved, go, deterministic=True)[0]
    assert g2.shape == attr2.shape
    shared = ip.backward(forward(attr, rasts, tri, ctx=ctx)[2], go, deterministic=True)[0]
    parts = [ip.backward(forward(attr, rasts[i:i + 1], tri, ctx=ctx)[2], go[i:i + 1],
                         deterministic=True)[0] for i in range(2)]
    assert np.array_equal(g2[0], parts[0])
    total = parts[0].astype(np.float64) + parts[1]
    assert (np.abs(shared - total) <= U32 * (np.abs(parts[0]) + np.abs(parts[1])
                                             + 2 * np.abs(total))).all()


def test_repeated_diff_attrs_repeat_columns_and_add_gradients(ctx, scene):
    """diff_attrs [2, 0, 2]: out_da's third pair copies the first; grad_rast_db and
    grad_attr equal those of [2, 0] with the two listings' upstream gradients added
    (one float32 addition: within u of the sum, per pixel)."""
    attr, rast, rast_db, tri, rng = scene
    _, da3, saved3 = forward(attr, rast, tri, rast_db, [2, 0, 2], ctx=ctx)
    out, da2, saved2 = forward(attr, rast, tri, rast_db, [2, 0], ctx=ctx)
    assert np.array_equal(da3[..., :4], da2) and np.array_equal(da3[..., 4:], da2[..., :2])
    go = rng.normal(size=out.shape).astype(np.float32)
    g3 = rng.normal(size=da3.shape).astype(np.float32)
    g2 = g3[..., :4].copy()
    g2[..., :2] += g3[..., 4:]
    a3 = ip.backward(saved3, go, g3, deterministic=True)
    a2 = ip.backward(saved2, go, g2, deterministic=True)
    for x, y in zip(a3, a2):
        assert np.array_equal(x, y)


def test_arguments_are_checked_once_by_the_op(ctx, scene):
    attr, rast, rast_db, tri, _ = scene
    with pytest.raises(ValueError, match="diff_attrs needs rast_db"):
        forward(attr, rast, tri, None, "all", ctx=ctx)
    with pytest.raises(ValueError, match=r"diff_attrs index 7 is out of range for attr with 5"):
        forward(attr, rast, tri, rast_db, [7], ctx=ctx)
    with pytest.raises(ValueError, match="diff_attrs must be None, 'all'"):
        forward(attr, rast, tri, rast_db, "some", ctx=ctx)
    with pytest.raises(ValueError, match="rast_db must have shape"):
        forward(attr, rast, tri, rast_db[:, :2], "all", ctx=ctx)
    with pytest.raises(ValueError, match="beyond tri's"):
        forward(attr, rast, tri[:3], ctx=ctx)


def test_unwanted_gradients_are_none_and_the_wanted_unchanged(ctx, scene):
    """needs: (attr, rast, rast_db); unwanted entries are None, the wanted ones the same
    bits as with every gradient wanted (deterministic)."""
    attr, rast, rast_db, tri, rng = scene
    out, out_da, saved = forward(attr, rast, tri, rast_db, "all", ctx=ctx)
    go = rng.normal(size=out.shape).astype(np.float32)
    gda = rng.normal(size=out_da.shape).astype(np.float32)
    full = ip.backward(saved, go, gda, deterministic=True)
    for needs in [(True, False, False), (False, True, False), (False, False, True),
                  (False, False, False)]:
        got = ip.backward(saved, go, gda, needs=needs, deterministic=True)
        for want, g, all_ in zip(needs, got, full):
            assert (g is None) if not want else np.array_equal(g, all_), needs


@pytest.mark.parametrize("columns", [8, 6, 5, 1])
def test_fetch_widths_give_the_same_bits_per_column(ctx, scene, columns):
    """Attribute rows are fetched 4, 2 or 1 floats a texel (whatever divides A): the first
    ``columns`` attributes of an 8-attribute set interpolate, derive and get gradients
    with the same bits whatever the width (every column's arithmetic is its own)."""
    _, rast, rast_db, tri, rng = scene
    attr8 = rng.normal(size=(int(tri.max()) + 1, 8)).astype(np.float32)
    out8, da8, saved8 = forward(attr8, rast, tri, rast_db, "all", ctx=ctx)
    go8 = rng.normal(size=out8.shape).astype(np.float32)
    gda8 = rng.normal(size=da8.shape).astype(np.float32)
    grad8 = ip.backward(saved8, go8, gda8, deterministic=True)[0]
    attr = np.ascontiguousarray(attr8[:, :columns])
    out, da, saved = forward(attr, rast, tri, rast_db, "all", ctx=ctx)
    assert np.array_equal(out, out8[..., :columns])
    assert np.array_equal(da, da8[..., :2 * columns])
    grad = ip.backward(saved, np.ascontiguousarray(go8[..., :columns]),
                       np.ascontiguousarray(gda8[..., :2 * columns]), deterministic=True)[0]
    assert np.array_equal(grad, grad8[:, :columns])


def test_buffer_texture_limit_is_a_clear_error(ctx, scene):
    attr, rast, _rast_db, tri, _ = scene
    forward(attr, rast, tri, ctx=ctx)
    names, limit = buffer_views._VIEWS[ctx]
    buffer_views._VIEWS[ctx] = (names, 8)
    try:
        with pytest.raises(ValueError, match="interpolate's attr needs .* texels of .* in one buffer"):
            forward(attr, rast, tri, ctx=ctx)
    finally:
        buffer_views._VIEWS[ctx] = (names, limit)
