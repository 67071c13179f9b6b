"""The fixed-point accumulation of deterministic=True (glraster.diff.compute.FixedPointSum):
the stated range and rounding against exact sums, bit-identical results whatever the order
of the additions (shuffled pixels, images swapped, chunking, history), and huge or
non-finite gradients (rescaled, or an error naming the argument, never a wrapped sum)."""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff import compute
from glraster.diff import interpolate as ip
from glraster.diff.ids import decode_ids
from glraster.errors import ArgumentError
from tests.diff.test_interpolate_gpu import forward, gpu_raster
from tests.diff.test_rasterize_backward import (U32, gpu_backward, gpu_rast, random_soup,
                                                upstream)


def bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


@pytest.fixture(autouse=True)
def fresh_guesses(monkeypatch):
    """Each test starts without the exponents of earlier calls."""
    monkeypatch.setattr(compute.FixedPointSum, "_guesses", {})


def test_exponent_is_the_largest_that_keeps_every_term_below_2_31():
    """largest 2^k < 2^31 <= largest 2^(k+1): every rounded term fits the biased low word
    (one atomic a term), and fewer than 2^32 - 1 terms sum below 2^63 with the bias."""
    assert compute.fixed_point_exponent(1.0, 1) == 30
    assert compute.fixed_point_exponent(0.75, 3 * 4096) == 31
    rng = np.random.default_rng(0)
    for largest, terms in zip(np.exp(rng.uniform(-60, 60, 200)), rng.integers(1, 1 << 32, 200)):
        k = compute.fixed_point_exponent(largest, int(terms))
        assert largest * 2.0 ** k < 2.0 ** 31 <= largest * 2.0 ** (k + 1)
        assert int(terms) * int(np.floor(largest * 2.0 ** k + 0.5)) + (1 << 31) < 1 << 63
    assert compute.fixed_point_exponent(1e-35, 4) == 127, "2^k stays a normal float32"
    assert compute.fixed_point_exponent(np.finfo(np.float32).max) == -97
    with pytest.raises(ValueError, match="terms per value"):
        compute.fixed_point_exponent(1.0, (1 << 32) - 1)


def test_deterministic_is_the_fixed_point_accumulation_of_the_three_ops(ctx):
    assert compute.accumulation(ctx, True, None, compute.FIXED_POINT_ACCUMULATIONS) == \
        "fixed_point"
    assert compute.accumulation(ctx, True) == "per_pixel", "texture's own name for its GPU fixed-point sum"
    with pytest.raises(ValueError, match="accumulate must be one of"):
        compute.accumulation(ctx, accumulate="per_pixel",
                             offered=compute.FIXED_POINT_ACCUMULATIONS)


@pytest.fixture
def interp_scene(ctx):
    pos, tri, res = random_soup(31, 60)
    rast, _ = gpu_raster(ctx, pos, tri, res)
    rng = np.random.default_rng(32)
    attr = rng.normal(size=(len(pos), 3)).astype(np.float32)
    go = rng.normal(size=rast.shape[:3] + (3,)).astype(np.float32)
    return attr, rast, tri, go


def _interpolate_terms(rast, tri, go):
    """The float32 terms of grad_attr (without diff_attrs: u g, v g, (1 - u - v) g, each
    one float32 rounding, as the shader forms them) and their vertex rows, (N, 3, A)."""
    flat, g = rast.reshape(-1, 4), go.reshape(-1, go.shape[-1])
    t = decode_ids(flat[:, 3])
    live = t >= 0
    u, v = flat[live, 0], flat[live, 1]
    w = np.float32(1) - u - v
    weights = np.stack([u, v, w], 1)                                    # float32
    terms = (weights[:, :, None] * g[live][:, None, :]).astype(np.float32)
    return terms, tri[t[live]]


def test_interpolate_sum_within_the_stated_bound_of_the_exact_sum(ctx, interp_scene):
    """|fixed point - exact sum of the float32 terms| <= n 2^-(k+1) (the rounding of each
    term) + u |sum| (the final float32 rounding) + 2^-50 sum |terms| (the float64 sum
    taken as exact here), k from the largest term and 3 terms per pixel."""
    attr, rast, tri, go = interp_scene
    _, _, saved = forward(attr, rast, tri, ctx=ctx)
    got = ip.backward(saved, go, deterministic=True)[0]
    terms, rows = _interpolate_terms(rast, tri, go)
    exact = np.zeros(attr.shape)
    magnitude = np.zeros(attr.shape)
    for c in range(attr.shape[1]):
        exact[:, c] = np.bincount(rows.ravel(), terms[:, :, c].ravel().astype(np.float64),
                                  len(attr))
        magnitude[:, c] = np.bincount(rows.ravel(), np.abs(terms[:, :, c]).ravel(), len(attr))
    n = np.bincount(rows.ravel(), minlength=len(attr))[:, None]
    k = compute.fixed_point_exponent(np.abs(terms).max(), 3 * rast[..., 0].size)
    bound = n * 2.0 ** -(k + 1) + U32 * np.abs(exact) + 2.0 ** -50 * magnitude
    err = np.abs(got - exact)
    assert np.abs(exact).max() > 1 and (err <= bound).all(), (err / bound).max()
    # the stated bound is tight enough to matter: below a float32 ulp of the largest sum
    assert (n * 2.0 ** -(k + 1)).max() < U32 * np.abs(exact).max()


def test_interpolate_sum_is_the_float32_of_the_exact_integer_sum(ctx, interp_scene):
    """Every value is float32(2^-k sum roundEven(t 2^k)) bit for bit (the integer sum
    exact, in Python integers): the bias and the carries between the words lose nothing,
    for sums of both signs crossing zero (random upstream gradients) and for sums of many
    terms crossing +-2^31 (a vertex shared by many pixels)."""
    attr, rast, tri, go = interp_scene
    _, _, saved = forward(attr, rast, tri, ctx=ctx)
    got = ip.backward(saved, go, deterministic=True)[0]
    terms, rows = _interpolate_terms(rast, tri, go)
    k = compute.fixed_point_exponent(np.abs(terms).max(), 3 * rast[..., 0].size)
    q = np.rint(np.ldexp(terms.astype(np.float64), k)).astype(np.int64)   # |q| < 2^31
    sums = np.zeros(attr.shape, object)
    np.add.at(sums, rows.ravel(), q.reshape(-1, attr.shape[1]).astype(object))
    assert max(abs(int(v)) for v in sums.ravel()) > 1 << 31, "some sums cross 2^31"
    want = np.array([[float(v) for v in row] for row in sums]) * 2.0 ** -k
    assert bits(got).tolist() == bits(want.astype(np.float32)).tolist()


def test_interpolate_bit_identical_for_shuffled_pixels_and_chunks(ctx, interp_scene,
                                                                  monkeypatch):
    """grad_attr sums the same terms whatever the pixel order: the pixels of rast and
    grad_out shuffled (one permutation), the dispatch cut into chunks, and every term
    added on its own (no local sums over runs of pixels)."""
    attr, rast, tri, go = interp_scene
    _, _, saved = forward(attr, rast, tri, ctx=ctx)
    want = ip.backward(saved, go, deterministic=True)[0]
    order = np.random.default_rng(33).permutation(rast[..., 0].size)
    shuffled = rast.reshape(-1, 4)[order].reshape(rast.shape)
    go_shuffled = go.reshape(-1, go.shape[-1])[order].reshape(go.shape)
    _, _, saved2 = forward(attr, shuffled, tri, ctx=ctx)
    got = ip.backward(saved2, go_shuffled, deterministic=True)[0]
    assert np.abs(want).max() > 0 and np.array_equal(bits(want), bits(got))
    monkeypatch.setattr(compute, "MAX_CHUNK_BYTES", 64 * 200)
    chunked = ip.backward(saved, go, deterministic=True)[0]
    assert np.array_equal(bits(want), bits(chunked))
    monkeypatch.setattr(compute, "RUN_PIXELS", 1)
    single = ip.backward(saved, go, deterministic=True)[0]
    assert np.array_equal(bits(want), bits(single)), "every term added on its own"


def test_rasterize_bit_identical_for_swapped_images_chunks_and_history(ctx, monkeypatch):
    """(V, 4) pos shared by two images: the images swapped (their terms added in the
    other order), every term added on its own (no local sums over runs of pixels), the
    dispatch in chunks, and a previous call with other exponents give the same bits."""
    pos, tri, res = random_soup(34)
    rast = gpu_rast(ctx, pos, tri, res)
    rng = np.random.default_rng(35)
    g1, g2 = upstream(rng, rast.shape), upstream(rng, rast.shape)
    rasts, gs = np.concatenate([rast, rast]), np.concatenate([g1, g2])
    want = gpu_backward(pos, tri, rasts, gs, ctx=ctx, deterministic=True)
    swapped = gpu_backward(pos, tri, rasts, np.concatenate([g2, g1]), ctx=ctx,
                           deterministic=True)
    assert np.abs(want).max() > 0 and np.array_equal(bits(want), bits(swapped))
    gpu_backward(pos, tri, rasts, gs * np.float32(2.0 ** 40), ctx=ctx, deterministic=True)
    after = gpu_backward(pos, tri, rasts, gs, ctx=ctx, deterministic=True)
    assert np.array_equal(bits(want), bits(after)), "the exponent depends on the call only"
    monkeypatch.setattr(compute, "RUN_PIXELS", 1)
    single = gpu_backward(pos, tri, rasts, gs, ctx=ctx, deterministic=True)
    assert np.array_equal(bits(want), bits(single))
    monkeypatch.setattr(compute, "RUN_PIXELS", 5)
    monkeypatch.setattr(compute, "MAX_CHUNK_BYTES", 16 * 640)
    chunked = gpu_backward(pos, tri, rasts, gs, ctx=ctx, deterministic=True)
    assert np.array_equal(bits(want), bits(chunked))


@pytest.mark.parametrize("power", [100, -40])
def test_huge_and_tiny_gradients_rescale_exactly(ctx, power):
    """Upstream gradients times 2^power: every term scales exactly, so the exponent moves
    by -power and the sums are the same integers: grad_pos times 2^power, bit for bit
    (with 2^100 the terms reach ~1e31: far past any fixed 64-bit range)."""
    pos, tri, res = random_soup(36)
    rast = gpu_rast(ctx, pos, tri, res)
    rng = np.random.default_rng(37)
    g, h = upstream(rng, rast.shape), upstream(rng, rast.shape)
    base = gpu_backward(pos, tri, rast, g, h, ctx=ctx, deterministic=True)
    scale = np.float32(2.0 ** power)
    scaled = gpu_backward(pos, tri, rast, g * scale, h * scale, ctx=ctx, deterministic=True)
    assert np.isfinite(scaled).all() and np.abs(base).max() > 0
    assert np.array_equal(bits(scaled), bits(base * scale))


def test_non_finite_terms_raise_naming_the_gradient(ctx, interp_scene):
    pos, tri, res = random_soup(38)
    rast = gpu_rast(ctx, pos, tri, res)
    g = upstream(np.random.default_rng(39), rast.shape)
    with np.errstate(over="ignore"):
        g[rast[..., 3] != 0] *= np.float32(3e38)        # terms overflow float32
    with pytest.raises(ArgumentError, match="grad_rast") as info:
        gpu_backward(pos, tri, rast, g, ctx=ctx, deterministic=True)
    assert info.value.argument == "grad_rast"
    attr, rast, tri, go = interp_scene
    _, _, saved = forward(attr, rast, tri, ctx=ctx)
    go = go.copy()
    go[rast[..., 3] != 0] = np.nan
    with pytest.raises(ArgumentError, match="grad_out"):
        ip.backward(saved, go, deterministic=True)
