"""The rasterize backward on the GPU (glraster.diff.rasterize.backward) against float64.

Three tiers:

* the float64 closed form written here (:func:`closed_form`, the shader's formulas step
  by step) against central finite differences of a float64 forward evaluated here
  (:func:`float64_forward`), triangle ids frozen; and against the reference module
  (glraster.diff.rasterize_reference.backward);
* GPU per-pixel terms against the float64 ones within a running error bound: the closed
  form is evaluated in :class:`Err` arithmetic, which carries beside each float64 value a
  first-order bound ``m`` on the error of the same expression evaluated in float32
  (|float32 - exact| <= u m, u = 2^-24), propagated operation by operation;
* GPU per-vertex sums against float64 within the sum of their pixels' bounds plus the
  float32 summation bound (atomics: (n - 1) u sum |c| for n terms in any order; the
  deterministic float64 sum: one rounding).

Upstream gradients are random normals on every channel (z/w and id must be ignored).
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster.conformance.scenes import load_scene
from glraster.diff import compute, rasterize_reference
from glraster.diff.ids import decode_ids
from glraster.diff import rasterize as dr
from glraster.diff.ops import RASTERIZE
from glraster.diff.saved import RasterizeSaved

U32 = 2.0 ** -24
# GLSL allows 2.5 ulp for division (the shader divides once, 1/S, and multiplies) and the
# compiler may contract a*b+c into fma: every operation of Err counts one rounding, so K
# covers the division's extra 1.5 ulp and leaves a margin. Measured max |err| / (u m) is
# reported by test_gpu_pixel_terms_within_running_error_bound.
K = 4.0

SCENES = ("basic_perspective_triangle", "grid_perspective_jitter", "slivers", "behind_camera",
          "icosphere")


# --------------------------------------------------------------------------- Err arithmetic


class Err:
    """A float64 value ``v`` with a first-order bound ``m``: the same expression evaluated
    in float32 (each operation rounded once) is within ``U32 * m`` of ``v``. Inputs that
    are float32 numbers are exact (m = 0)."""

    __array_priority__ = 1000

    def __init__(self, v, m=None):
        self.v = np.asarray(v, np.float64)
        self.m = np.zeros_like(self.v) if m is None else m

    @staticmethod
    def of(x):
        return x if isinstance(x, Err) else Err(x)

    def __add__(self, o):
        o = Err.of(o)
        r = self.v + o.v
        return Err(r, self.m + o.m + np.abs(r))

    __radd__ = __add__

    def __sub__(self, o):
        o = Err.of(o)
        r = self.v - o.v
        return Err(r, self.m + o.m + np.abs(r))

    def __rsub__(self, o):
        return Err.of(o) - self

    def __neg__(self):
        return Err(-self.v, self.m)

    def __mul__(self, o):
        o = Err.of(o)
        r = self.v * o.v
        return Err(r, self.m * np.abs(o.v) + np.abs(self.v) * o.m + np.abs(r))

    __rmul__ = __mul__

    def __truediv__(self, o):
        o = Err.of(o)
        r = self.v / o.v
        return Err(r, self.m / np.abs(o.v) + np.abs(r) * o.m / np.abs(o.v) + np.abs(r))

    def __rtruediv__(self, o):
        return Err.of(o) / self


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def vadd(a, b):
    return tuple(x + y for x, y in zip(a, b))


# --------------------------------------------------------------------------- float64 side


def covered(rast, tri):
    """(b, y, x, t) of the covered pixels of a GPU rast (t: triangle index)."""
    ids = decode_ids(rast[..., 3])
    b, y, x = np.nonzero(ids >= 0)
    return b, y, x, ids[b, y, x]


def _vertices(pos, tri, b, t):
    pos3 = pos if pos.ndim == 3 else pos[None]
    pb = b if pos.ndim == 3 else np.zeros_like(b)
    vert = tri[t].astype(np.int64)
    return pos3[pb[:, None], vert], pb[:, None] * pos3.shape[1] + vert


def closed_form(pos, tri, rast, grad_rast, grad_db=None, space="persp"):
    """Per covered pixel, the shader's closed form in :class:`Err` arithmetic.

    Returns (index (N, 3) flat vertex rows, terms: list over the 3 corners of
    (Err dL/dx, Err dL/dy, Err dL/dw)).
    """
    _, height, width, _ = rast.shape
    b, y, x, t = covered(rast, tri)
    clip, index = _vertices(np.asarray(pos, np.float64), tri, b, t)
    half = (Err(width / 2.0), Err(height / 2.0))
    ndc = ((2.0 * x + 1.0) / Err(float(width)) - 1.0, (2.0 * y + 1.0) / Err(float(height)) - 1.0)
    V = []
    for j in range(3):
        p = clip[:, j]
        w = Err(p[:, 3])
        V.append((half[0] * (Err(p[:, 0]) - w * ndc[0]), half[1] * (Err(p[:, 1]) - w * ndc[1]), w))
    N = [cross(V[(k + 1) % 3], V[(k + 2) % 3]) for k in range(3)]
    g = grad_rast[b, y, x].astype(np.float64)
    g3 = (Err(g[:, 0]), Err(g[:, 1]), Err(np.zeros(len(b))))
    zero = Err(np.zeros(len(b)))
    G = [(zero, zero, zero) for _ in range(3)]
    if grad_db is not None:
        h = grad_db[b, y, x].astype(np.float64)
        hx = (Err(h[:, 0]), Err(h[:, 2]), zero)
        hy = (Err(h[:, 1]), Err(h[:, 3]), zero)
    gA = gB = (zero, zero, zero)
    if space == "screen":
        det = V[0][0] * N[0][0] + V[0][1] * N[0][1] + V[0][2] * N[0][2]
        inv = 1.0 / det
        w = [V[j][2] for j in range(3)]
        e = [N[j][2] for j in range(3)]
        ge = tuple(g3[k] * w[k] * inv for k in range(3))
        gw = [g3[k] * e[k] * inv for k in range(3)]
        gdet = -(g3[0] * (e[0] * w[0]) + g3[1] * (e[1] * w[1]))
        if grad_db is not None:
            gA = tuple(hx[k] * w[k] * inv for k in range(3))
            gB = tuple(hy[k] * w[k] * inv for k in range(3))
            q = [hx[k] * N[k][0] + hy[k] * N[k][1] for k in range(3)]
            gw = [gw[k] + q[k] * inv for k in range(3)]
            gdet = gdet - (q[0] * w[0] + q[1] * w[1])
        gdet = gdet * inv * inv
        G = [(gdet * N[j][0], gdet * N[j][1], gdet * N[j][2] + gw[j]) for j in range(3)]
    else:
        S = N[0][2] + N[1][2] + N[2][2]
        inv = 1.0 / S
        b0, b1 = N[0][2] * inv, N[1][2] * inv
        gb = g3[0] * b0 + g3[1] * b1
        ge = tuple((g3[k] - gb) * inv for k in range(3))
        if grad_db is not None:
            SA = N[0][0] + N[1][0] + N[2][0]
            SB = N[0][1] + N[1][1] + N[2][1]
            db = ((N[0][0] - b0 * SA) * inv, (N[0][1] - b0 * SB) * inv,
                  (N[1][0] - b1 * SA) * inv, (N[1][1] - b1 * SB) * inv)
            hh = (Err(h[:, 0]), Err(h[:, 1]), Err(h[:, 2]), Err(h[:, 3]))
            D = hh[0] * db[0] + hh[1] * db[1] + hh[2] * db[2] + hh[3] * db[3]
            gx = tuple(hx[k] - (hx[0] * b0 + hx[1] * b1) for k in range(3))
            gy = tuple(hy[k] - (hy[0] * b0 + hy[1] * b1) for k in range(3))
            gA = tuple(gx[k] * inv for k in range(3))
            gB = tuple(gy[k] * inv for k in range(3))
            rA, rB = SA * inv, SB * inv
            ge = tuple(ge[k] - (D + rA * gx[k] + rB * gy[k]) * inv for k in range(3))
    for k in range(3):
        n = (gA[k], gB[k], ge[k])
        k1, k2 = (k + 1) % 3, (k + 2) % 3
        G[k1] = vadd(G[k1], cross(V[k2], n))
        G[k2] = vadd(G[k2], cross(n, V[k1]))
    terms = []
    for j in range(3):
        gx_, gy_ = half[0] * G[j][0], half[1] * G[j][1]
        terms.append((gx_, gy_, G[j][2] - (ndc[0] * gx_ + ndc[1] * gy_)))
    return index, terms


def term_arrays(terms):
    """(N, 3, 4) values and bounds (z channel 0) from closed_form's terms."""
    v = np.zeros((len(terms[0][0].v), 3, 4))
    m = np.zeros_like(v)
    for j, (gx, gy, gw) in enumerate(terms):
        for c, e in zip((0, 1, 3), (gx, gy, gw)):
            v[:, j, c], m[:, j, c] = e.v, e.m
    return v, m


def per_vertex(index, values, num):
    out = np.zeros((num, 4))
    for c in range(4):
        out[:, c] = np.bincount(index.ravel(), weights=values[:, :, c].ravel(), minlength=num)
    return out


def float64_forward(pos, tri, rast_ids, resolution, space="persp"):
    """(u, v, du/dx, du/dy, dv/dx, dv/dy) (N, 6) float64 at the covered pixels of a frozen
    id map, from the homogeneous window vertices (written here, independently of the
    closed form's pixel-relative frame)."""
    height, width = resolution
    b, y, x, t = rast_ids
    clip, _ = _vertices(pos, tri, b, t)
    X = (clip[..., 0] + clip[..., 3]) * width / 2
    Y = (clip[..., 1] + clip[..., 3]) * height / 2
    w = clip[..., 3]
    v = np.stack([X, Y, w], -1)                                  # (N, 3, 3)
    rows = np.cross(v[:, [1, 2, 0]], v[:, [2, 0, 1]])           # adj(M) rows
    p = np.stack([x + 0.5, y + 0.5, np.ones(len(x))], -1)
    e = np.einsum("nkc,nc->nk", rows, p)
    A, B = rows[..., 0], rows[..., 1]
    if space == "screen":
        det = np.einsum("nc,nc->n", rows[:, 0], v[:, 0])[:, None]
        bary, dx, dy = e * w / det, A * w / det, B * w / det
    else:
        S = e.sum(-1, keepdims=True)
        bary = e / S
        dx = (A - bary * A.sum(-1, keepdims=True)) / S
        dy = (B - bary * B.sum(-1, keepdims=True)) / S
    return np.stack([bary[:, 0], bary[:, 1], dx[:, 0], dy[:, 0], dx[:, 1], dy[:, 1]], -1)


# --------------------------------------------------------------------------- fixtures


def gpu_rast(ctx, pos, tri, resolution, space="persp"):
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=resolution, ctx=ctx,
                                     grad_db=False, space=space)
    return rast


def saved_of(pos, tri, rast, space="persp", ctx=None):
    """The RasterizeSaved of a raster (its ids frozen), as the forward would make it; a
    (V, 4) pos with a batch of rasters shares its vertices among them."""
    return RasterizeSaved(pos=pos, tri=np.asarray(tri, np.int32), resolution=rast.shape[1:3],
                          ranges=None, rast=rast, space=space, ctx=ctx)


def gpu_backward(pos, tri, rast, g, h=None, *, ctx, space="persp", **options):
    """dL/d pos from the GPU core (options: deterministic, accumulate)."""
    (grad,) = dr.backward(saved_of(pos, tri, rast, space, ctx), g, h, **options)
    return grad


def gpu_pixels(pos, tri, rast, g, h=None, *, ctx, space="persp"):
    return dr.backward_pixels(saved_of(pos, tri, rast, space, ctx), g, h)


def reference_backward(pos, tri, rast, g, h=None, space="persp"):
    """dL/d pos from the float64 core, on the same frozen ids."""
    saved = saved_of(np.asarray(pos, np.float64), tri, rast.astype(np.float64), space)
    (grad,) = rasterize_reference.backward(saved, g.astype(np.float64),
                                           None if h is None else h.astype(np.float64))
    return grad


def random_soup(seed=0, count=40, resolution=(48, 64)):
    """Triangles of 5-30 px with w in [0.5, 3] (perspective), overlapping."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-0.8, 0.8, (count, 1, 2))
    spread = rng.normal(0.0, 0.25, (count, 3, 2))
    w = rng.uniform(0.5, 3.0, (count, 3, 1))
    z = rng.uniform(-0.9, 0.9, (count, 3, 1)) * w
    pos = np.concatenate([(centre + spread) * w, z, w], -1).reshape(-1, 4).astype(np.float32)
    return pos, np.arange(3 * count, dtype=np.int32).reshape(count, 3), resolution


def upstream(rng, shape):
    return rng.normal(size=shape).astype(np.float32)


# --------------------------------------------------------------------------- tier 1


@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("with_db", [False, True])
def test_closed_form_matches_central_differences(ctx, space, with_db):
    """Float64 closed form against central differences of the float64 forward, ids frozen.
    Step 1e-6 (clip units ~1): truncation ~1e-12 relative, rounding ~1e-10; tolerance
    1e-6 of the gradient's largest entry."""
    pos, tri, res = random_soup(1, 25, (32, 40))
    rast = gpu_rast(ctx, pos, tri, res, space)
    ids = covered(rast, tri)
    assert len(ids[0]) > 200, "the scene must cover pixels"
    rng = np.random.default_rng(2)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    h = h if with_db else None
    index, terms = closed_form(pos, tri, rast, g, h, space)
    v, _ = term_arrays(terms)
    analytic = per_vertex(index, v, len(pos))
    assert np.abs(analytic).max() > 0

    b, y, x, _ = ids
    gp = g[b, y, x].astype(np.float64)
    hp = h[b, y, x].astype(np.float64) if with_db else np.zeros((len(b), 4))

    def loss(p):
        f = float64_forward(p, tri, ids, res, space)
        return (f[:, 0] * gp[:, 0] + f[:, 1] * gp[:, 1]).sum() + (f[:, 2:] * hp).sum()

    p64 = pos.astype(np.float64)
    step = 1e-6
    vertices = np.unique(tri[ids[3]].ravel())[::7]
    checked = 0
    for vtx in vertices:
        for c in (0, 1, 2, 3):
            up, down = p64.copy(), p64.copy()
            up[vtx, c] += step
            down[vtx, c] -= step
            fd = (loss(up) - loss(down)) / (2 * step)
            assert abs(fd - analytic[vtx, c]) <= 1e-6 * np.abs(analytic).max(), (vtx, c)
            checked += 1
    assert checked >= 20


@pytest.mark.parametrize("space", ["persp", "screen"])
def test_closed_form_matches_reference_module(ctx, space):
    """This file's float64 closed form (pixel-relative frame) against
    glraster.diff.rasterize_reference (absolute frame): both float64, 1e-9 of the largest entry."""
    pos, tri, res = random_soup(3)
    rast = gpu_rast(ctx, pos, tri, res, space)
    rng = np.random.default_rng(4)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    index, terms = closed_form(pos, tri, rast, g, h, space)
    mine = per_vertex(index, term_arrays(terms)[0], len(pos))
    theirs = reference_backward(pos, tri, rast, g, h, space)
    assert np.abs(theirs).max() > 0
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-9 * np.abs(theirs).max())


# --------------------------------------------------------------------------- tier 2 and 3


def _scene(name):
    s = load_scene(name)
    return np.asarray(s.pos, np.float32), np.asarray(s.tri, np.int32), tuple(s.resolution)


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("space", ["persp", "screen"])
def test_gpu_pixel_terms_within_running_error_bound(ctx, name, space):
    """Every covered pixel's nine terms within K u m of float64 (m: the Err bound)."""
    pos, tri, res = _scene(name)
    rast = gpu_rast(ctx, pos, tri, res, space)
    rng = np.random.default_rng(5)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    b, y, x, _ = covered(rast, tri)
    assert len(b) > 0, "the scene must cover pixels"
    _index, terms = closed_form(pos, tri, rast, g, h, space)
    want, bound = term_arrays(terms)
    got = gpu_pixels(pos, tri, rast, g, h, ctx=ctx, space=space)[b, y, x]
    assert np.abs(got).max() > 0
    err = np.abs(got - want)
    ratio = err / np.maximum(U32 * bound, 1e-300)
    assert (ratio <= K).all(), f"{name}: max |err| / (u m) = {ratio.max():.2f} > {K}"
    empty = gpu_pixels(pos, tri, rast, g, h, ctx=ctx, space=space)
    empty[b, y, x] = 0
    assert not empty.any(), "empty pixels must contribute nothing"


@pytest.mark.parametrize("run", [1, compute.RUN_PIXELS])
@pytest.mark.parametrize("accumulate", compute.FIXED_POINT_ACCUMULATIONS)
@pytest.mark.parametrize("name", ["grid_perspective_jitter", "icosphere", "slivers"])
def test_gpu_vertex_gradients_within_bound(ctx, name, accumulate, run, monkeypatch):
    """Per vertex: |gpu - float64| <= sum of its pixels' K u m + the summation bound
    ((n - 1) u sum |c| for float32 sums in any order and grouping: atomics, and local sums
    over runs of pixels added by atomics; n 2^-(k+1) for the fixed-point sums, k from an
    upper bound on the largest term, 3 terms per pixel) + u |sum|; every term added on its
    own (run 1) and with local sums."""
    if accumulate == "atomic_float" and not compute.has_atomic_float(ctx):
        pytest.skip("the driver has no GL_NV_shader_atomic_float")
    monkeypatch.setattr(compute, "RUN_PIXELS", run)
    pos, tri, res = _scene(name)
    rast = gpu_rast(ctx, pos, tri, res)
    rng = np.random.default_rng(6)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    index, terms = closed_form(pos, tri, rast, g, h)
    want, bound = term_arrays(terms)
    total = per_vertex(index, want, len(pos))
    pixel_bound = per_vertex(index, K * U32 * bound, len(pos))
    magnitude = per_vertex(index, np.abs(want), len(pos))
    count = np.bincount(index.ravel(), minlength=len(pos))[:, None]
    if accumulate == "fixed_point":
        largest = (np.abs(want) + K * U32 * bound).max()
        k = compute.fixed_point_exponent(largest, 3 * rast[..., 0].size)
        summation = count * 2.0 ** -(k + 1)
    else:
        summation = np.maximum(count - 1, 0) * U32 * (magnitude + pixel_bound)
    tol = pixel_bound + summation + U32 * np.abs(total)
    got = gpu_backward(pos, tri, rast, g, h, ctx=ctx, accumulate=accumulate)
    assert got.shape == pos.shape and got.dtype == np.float32
    assert np.abs(got).max() > 0 and not got[:, 2].any(), "dL/dz must be 0"
    assert (np.abs(got - total) <= tol).all()


def test_pixels_whose_ids_differ_from_the_reference_are_masked_and_counted(ctx):
    """Against the reference's own coverage (llvmpipe's rule modelled): pixels whose ids
    differ get no upstream gradient on either side and are counted (< 1% of the covered
    pixels); the rest must agree within the tier-3 bound's scale (1e-4 of the largest)."""
    pos, tri, res = _scene("grid_perspective_jitter")
    rast = gpu_rast(ctx, pos, tri, res)
    _, saved = RASTERIZE.forward(pos.astype(np.float64), tri=tri, resolution=res)
    gpu_ids = decode_ids(rast[..., 3])
    differ = gpu_ids != saved.tri_id
    n_covered = int((gpu_ids >= 0).sum())
    assert n_covered > 0
    assert differ.sum() <= 0.01 * n_covered, f"{differ.sum()} of {n_covered} pixels differ"
    rng = np.random.default_rng(7)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    g[differ], h[differ] = 0, 0
    (want,) = rasterize_reference.backward(saved, g.astype(np.float64), h.astype(np.float64))
    got = gpu_backward(pos, tri, rast, g, h, ctx=ctx)
    assert np.abs(want).max() > 0
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_deterministic_is_bit_identical_over_three_runs(ctx):
    pos, tri, res = _scene("icosphere")
    rast = gpu_rast(ctx, pos, tri, res)
    rng = np.random.default_rng(8)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    runs = [gpu_backward(pos, tri, rast, g, h, ctx=ctx, deterministic=True)
            for _ in range(3)]
    assert np.abs(runs[0]).max() > 0
    for other in runs[1:]:
        assert np.array_equal(runs[0].view(np.uint32), other.view(np.uint32))


def test_batches_equal_separate_calls_and_shared_positions_sum_them(ctx):
    """(B, V, 4) pos: item b equals a call on item b alone (deterministic: bit for bit);
    (V, 4) pos with a batch of rasters: the sum of the items (each side rounded once from
    float64 sums: within u of each part and u of the total)."""
    pos, tri, res = random_soup(9)
    pos2 = np.stack([pos, pos * np.float32(1.1)])
    rasts = np.concatenate([gpu_rast(ctx, p, tri, res) for p in pos2])
    rng = np.random.default_rng(10)
    g, h = upstream(rng, rasts.shape), upstream(rng, rasts.shape)
    both = gpu_backward(pos2, tri, rasts, g, h, ctx=ctx, deterministic=True)
    assert both.shape == pos2.shape
    for i in range(2):
        one = gpu_backward(pos2[i], tri, rasts[i:i + 1], g[i:i + 1], h[i:i + 1],
                                    ctx=ctx, deterministic=True)
        assert np.array_equal(both[i], one)
    same = np.concatenate([rasts[:1], rasts[:1]])
    shared = gpu_backward(pos, tri, same, g, h, ctx=ctx, deterministic=True)
    parts = [gpu_backward(pos, tri, same[i:i + 1], g[i:i + 1], h[i:i + 1], ctx=ctx,
                                   deterministic=True) for i in range(2)]
    total = parts[0].astype(np.float64) + parts[1]
    tol = U32 * (np.abs(parts[0]) + np.abs(parts[1]) + 2 * np.abs(total))
    assert (np.abs(shared - total) <= tol).all()


def test_chunked_dispatch_equals_one_dispatch(ctx, monkeypatch):
    """Inputs larger than one storage buffer are processed in chunks of pixels: same bits."""
    pos, tri, res = random_soup(11)
    rast = gpu_rast(ctx, pos, tri, res)
    rng = np.random.default_rng(12)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    whole = gpu_pixels(pos, tri, rast, g, h, ctx=ctx)
    monkeypatch.setattr(compute, "MAX_CHUNK_BYTES", 48 * 640)
    parts = gpu_pixels(pos, tri, rast, g, h, ctx=ctx)
    assert np.array_equal(whole, parts)


@pytest.mark.parametrize("batched_pos", [False, True])
def test_accumulating_chunks_and_tiles_give_the_same_sums(ctx, monkeypatch, batched_pos):
    """The accumulating passes run 32 x 32-pixel tiles over the stacked B H rows, in chunks
    of whole rows: a frame whose sides are no multiple of the tile, three images (tiles
    across image borders) and 5-row chunks (chunk borders inside tiles) give the bits of
    one dispatch (deterministic) and sums within float32 reordering of them (atomic)."""
    pos, tri, res = random_soup(21, resolution=(37, 45))
    if batched_pos:
        pos = np.stack([pos, pos * np.float32(1.05), pos[::-1].copy()])
        rast = gpu_rast(ctx, pos, tri, res)
    else:
        rast = np.concatenate([gpu_rast(ctx, pos, tri, res)] * 3)
    rng = np.random.default_rng(22)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    det = gpu_backward(pos, tri, rast, g, h, ctx=ctx, deterministic=True)
    atomic = gpu_backward(pos, tri, rast, g, h, ctx=ctx)
    monkeypatch.setattr(compute, "MAX_CHUNK_BYTES", 16 * 45 * 5)
    assert np.array_equal(gpu_backward(pos, tri, rast, g, h, ctx=ctx, deterministic=True), det)
    parts = gpu_backward(pos, tri, rast, g, h, ctx=ctx)
    exact = reference_backward(pos, tri, rast, g, h)
    scale = np.abs(exact).max()
    assert np.abs(parts - exact).max() <= 1e-4 * scale
    assert np.abs(atomic - exact).max() <= 1e-4 * scale
    assert np.abs(det - exact).max() <= 1e-4 * scale


def test_accumulation_choice_and_atomic_float_on_llvmpipe(ctx):
    mode = compute.accumulation(ctx)
    if ctx.is_llvmpipe:
        assert compute.has_atomic_float(ctx), "llvmpipe offers GL_NV_shader_atomic_float"
    assert mode == ("atomic_float" if compute.has_atomic_float(ctx) else "cas")
    assert compute.accumulation(ctx, deterministic=True) == "per_pixel"
    with pytest.raises(ValueError, match="accumulate must be one of"):
        compute.accumulation(ctx, accumulate="sorted")
