"""The GPU texture op (glraster.diff.texture, through glraster.diff.ops.TEXTURE) against
the float64 reference, per pixel,
within a float32 error bound; the GPU pyramid; accumulation modes; the GL sampler probe.

Per-pixel bound (u = 2^-24, K = 4 for GLSL's division and log2 (2.5 / 3 ulp), fma
contraction and margin), with T = max |texel| over every level, G = sum_c |dL/d out_c| of
the pixel, X = 4 + |s| Wt + |t| Ht (+ 2 N for a cube map: the projection's division) the
magnitude of the texel position x = s W - 0.5 (its float32 rounding moves the bilinear
weights by u X), and Λ = 8 + |level| (the level's float32 evaluation, about 3 u from log2
and the squares, plus the bias's addition u |level|, moves the level weights):

    out                  K u T (X + 2 Λ)
    grad_uv              K u (G T (Wt + Ht)(X + 2 Λ) / m + 16 R)     m = max |d_k| (cube), else 1
    grad_mip_level_bias  K u G T (X + 2 Λ)
    grad_uv_da           K u (D G T (X + 2 Λ) + 16 R)      D = |d level / d uv_da| (from the
                                                          reference: grad_uv_da / grad_bias)

(R = the largest |reference entry| of the pixel: d level / d(a, b, c, d) has terms such as
1/2 - (A - B) / (4 sqrt(((A - B)/2)^2 + C^2)) that cancel to ~C^2/(A - B)^2 when the
footprint is elongated along an axis, so a small entry carries an error of a few u times
the pixel's largest one)
    grad_tex (per texel) K u S(G (X + 2 Λ)) + u (n S(G) + L S(G))   atomics (n = pixels
                         reading the texel, L levels pulled back), or K u S(G (X + 2 Λ)) +
                         u |ref| + L u S(G) deterministic; S(v) = the sum of v over the pixels
                         reading the texel (texture_reference.texel_sums)

Pixels within 1e-4 texels of a texel boundary or of a level-rounding point (the kinks of
the lookup; float32 and float64 may land on different sides) are masked: their upstream
gradient is 0 and, for the piecewise-constant modes, their out is not compared. At least
half the pixels remain (asserted).
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff import buffer_views
from glraster.diff import compute as bg
from glraster.diff import texture as tx
from glraster.diff import texture_args as ta
from glraster.diff import texture_reference as tr
from tests.diff.test_texture_reference import (
    BOUNDARIES_2D,
    MODES_2D,
    make_inputs,
    safe,
    texture_backward,
    texture_forward,
)

U = 2.0 ** -24
K = 4.0


def _f32(*arrays):
    return [None if a is None else np.asarray(a, np.float32) for a in arrays]


def compare(ctx, tex, uv, da, bias, mode, boundary, mip=None, max_mip_level=None, seed=0,
            deterministic=False, accumulate=None):
    """GPU against float64 on the same float32 inputs; returns {name: (err/bound max,
    relative error max, p99.9, n)}; asserts every error within its bound."""
    tex, uv, da, bias = _f32(tex, uv, da, bias)
    mip = None if mip is None else _f32(*mip)
    rng = np.random.default_rng(seed + 7)
    ref_out, saved64 = texture_forward(tex, uv, da, bias, mip, mode, boundary, max_mip_level)
    out, saved = texture_forward(tex, uv, da, bias, mip, mode, boundary, max_mip_level,
                                 dtype=np.float32, ctx=ctx)
    assert out.dtype == np.float32 and out.shape == ref_out.shape
    args = saved64.args
    mask = safe(args, 1e-4)
    assert mask.mean() >= 0.5, f"only {mask.sum()} of {mask.size} pixels are comparable"
    g = rng.normal(size=out.shape).astype(np.float32)
    g.reshape(mask.size, -1)[~mask] = 0.0
    ref = texture_backward(saved64, g)
    gpu = texture_backward(saved, g, deterministic=deterministic, accumulate=accumulate)

    geo = tr.lookup_geometry(args)
    h0, w0 = args.shapes[0]
    T = max(np.abs(lv).max() for lv in saved64.levels)
    X = 4 + np.abs(geo["s"]) * w0 + np.abs(geo["t"]) * h0
    if args.cube:
        X = X + 2 * w0
    lam = 8 + np.abs(np.where(np.isfinite(geo["raw_level"]), geo["raw_level"], 0.0))
    spread = X + 2 * lam
    G = np.abs(g).reshape(mask.size, -1).sum(axis=1)
    m = np.abs(args.uv.reshape(mask.size, -1)).max(axis=1) if args.cube else np.ones(mask.size)
    report = {}

    def check(name, got, want, bound, rows=None):
        got = np.asarray(got, np.float64).reshape(len(bound), -1)
        want = np.asarray(want, np.float64).reshape(len(bound), -1)
        if rows is not None:
            got, want, bound = got[rows], want[rows], bound[rows]
        err = np.abs(got - want)
        ratio = err / (bound.reshape(len(bound), -1) + 1e-30)
        scale = max(np.abs(want).max(), 1e-30)
        rel = err / scale
        report[name] = (float(ratio.max()), float(rel.max()), float(np.quantile(rel, 0.999)),
                        int(err.size))
        assert ratio.max() <= 1.0, f"{name}: error {err.max():.3e} beyond its bound " \
            f"(ratio {ratio.max():.2f})"

    piecewise = mode in ("nearest", "linear-mipmap-nearest")
    check("out", out, ref_out, K * U * T * spread, rows=mask if piecewise else None)
    grad_tex, grad_uv, grad_da, grad_bias, grad_mip = gpu
    r_tex, r_uv, r_da, r_bias, r_mip = ref
    check("grad_uv", grad_uv, r_uv,
          K * U * (G * T * (w0 + h0) * spread / m)[:, None]
          + K * U * 16 * np.abs(r_uv.reshape(mask.size, -1)).max(axis=1, keepdims=True))
    if bias is not None:
        check("grad_mip_level_bias", grad_bias, r_bias, K * U * G * T * spread)
    if da is not None:
        assert grad_da.shape == da.shape
        rb = np.abs(r_bias.reshape(mask.size, 1)) if bias is not None else None
        if rb is not None:
            D = np.where(rb > 0, np.abs(r_da.reshape(mask.size, -1)) / np.where(rb > 0, rb, 1), 0)
            check("grad_uv_da", grad_da, r_da, K * U * (D * (G * T * spread)[:, None]
                                                       + 16 * np.abs(r_da.reshape(mask.size, -1))
                                                       .max(axis=1, keepdims=True)))
    # texel gradients
    shape = args.uv.shape[:3] + (1,)
    S_spread = tr.texel_sums(saved64, np.broadcast_to((G * spread).reshape(shape),
                                                      out.shape))
    S = tr.texel_sums(saved64, np.broadcast_to(G.reshape(shape), out.shape))
    n = tr.texel_sums(saved64, np.ones(out.shape))
    mode_used = bg.accumulation(ctx, deterministic, accumulate)
    L = args.levels
    targets = [("grad_tex", grad_tex, r_tex, None)]
    if mip is not None:
        targets = [("grad_tex", grad_tex, r_tex, None)]
    for name, got, want, _ in targets:
        if mode_used == "per_pixel":
            bound = K * U * S_spread + U * np.abs(want) + L * U * S
        else:
            bound = K * U * S_spread + U * (n + L) * S
        bound = bound + 1e-30
        check(name, got, want, bound.reshape(-1, 1))
    if mip is not None:
        for k, (got, want) in enumerate(zip(grad_mip, r_mip)):
            err = np.abs(got - want).max()
            scale = np.abs(want).max()
            assert err <= 64 * U * max(scale, 1e-30) * max(1.0, n.max()), f"mip[{k}]: {err}"
    return report


@pytest.mark.parametrize("boundary", BOUNDARIES_2D)
@pytest.mark.parametrize("mode", MODES_2D)
def test_2d_gpu_matches_the_reference(ctx, mode, boundary):
    tex, uv, da, bias = make_inputs(21, boundary, batch=2, image=(16, 20), tex_size=(24, 40))
    compare(ctx, tex, uv, da, bias, mode, boundary)


@pytest.mark.parametrize("mode", MODES_2D)
def test_cube_gpu_matches_the_reference(ctx, mode):
    tex, uv, da, bias = make_inputs(22, "cube", batch=2, image=(16, 20), tex_size=(12, 12))
    compare(ctx, tex, uv, da, bias, mode, "cube")


@pytest.mark.parametrize("channels", [1, 2, 4, 6, 8])
def test_every_texel_fetch_width_matches_the_reference(ctx, channels):
    """The levels and dL/d out are read 4, 2 or 1 floats a fetch (the widest that divides
    the channel count: glraster.diff.texture._texel_vec), uv 2 or 3."""
    assert tx._texel_vec(channels) == (4 if channels % 4 == 0 else 2 if channels % 2 == 0
                                       else 1)
    tex, uv, da, bias = make_inputs(24, "wrap", tex_size=(10, 14), channels=channels)
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "wrap")
    tex, uv, da, bias = make_inputs(25, "cube", tex_size=(6, 6), channels=channels)
    compare(ctx, tex, uv, da, bias, "linear", "cube")


def test_a_buffer_texture_too_large_for_the_driver_is_refused(ctx):
    """Past GL_MAX_TEXTURE_BUFFER_SIZE texels a view is refused with a ValueError naming
    what needed it (llvmpipe allows 2^27, beyond its 128 MiB storage buffers: the limit is
    lowered here)."""
    tex, uv, da, bias = make_inputs(26, "wrap", tex_size=(8, 8), channels=4)
    tex, uv = tex.astype(np.float32), uv.astype(np.float32)
    tx.forward(tex, uv, ctx=ctx)     # the views exist
    names, limit = buffer_views._VIEWS[ctx]
    buffer_views._VIEWS[ctx] = (names, 32)     # fewer texels than tex has
    try:
        with pytest.raises(ValueError,
                           match=r"the texture and its mip levels needs \d+ texels of 16 bytes"):
            tx.forward(tex, uv, ctx=ctx)
    finally:
        buffer_views._VIEWS[ctx] = (names, limit)
    tx.forward(tex, uv, ctx=ctx)


def test_batched_odd_texture_user_mips_and_max_mip_level(ctx):
    tex, uv, da, bias = make_inputs(23, "clamp", tex_size=(13, 7), tex_batch=2, channels=5)
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "clamp")
    rng = np.random.default_rng(24)
    shapes = ta.level_shapes(13, 7)
    mip = [rng.normal(size=(2,) + s + (5,)) for s in shapes[1:]]
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "clamp", mip=mip)
    tex, uv, da, bias = make_inputs(31, "clamp", tex_size=(13, 7), tex_batch=2, channels=5,
                                    level_range=(0.1, 0.9))
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "clamp", max_mip_level=1)


@pytest.mark.parametrize("accumulate", bg.ACCUMULATIONS)
def test_every_accumulation_is_within_the_bound(ctx, accumulate):
    if accumulate == "atomic_float" and not bg.has_atomic_float(ctx):
        pytest.skip("the driver has no GL_NV_shader_atomic_float")
    tex, uv, da, bias = make_inputs(25, "wrap", batch=2, image=(24, 24), tex_size=(8, 8))
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "wrap", accumulate=accumulate)
    tex, uv, da, bias = make_inputs(26, "cube", batch=1, image=(24, 24), tex_size=(4, 4))
    compare(ctx, tex, uv, da, bias, "linear-mipmap-linear", "cube", accumulate=accumulate)


def test_deterministic_backward_is_bit_identical(ctx):
    tex, uv, da, bias = _f32(*make_inputs(27, "wrap", batch=2, image=(32, 32), tex_size=(8, 8)))
    out, saved = texture_forward(tex, uv, da, bias, dtype=np.float32, ctx=ctx)
    g = np.random.default_rng(28).normal(size=out.shape).astype(np.float32)
    first = texture_backward(saved, g, deterministic=True)
    for _ in range(2):
        again = texture_backward(saved, g, deterministic=True)
        for a, b in zip(first[:4], again[:4]):
            assert a.tobytes() == b.tobytes()


def test_deterministic_texel_sums_are_exact_at_both_ends_of_the_range(ctx):
    """The deterministic backward's 64-bit fixed point: 4096 pixels of one 1 x 1 texture
    (nearest) with gradients of mixed signs up to 1e30, and one texel whose terms cancel
    to exactly 0. The fixed-point sum differs from the float64 sum by at most 2^-k per term
    (k = fixed_point_shift: 2^-28 of max |g| or less), far below the float32
    rounding of the result (u |sum|), and no accumulator overflows."""
    n = 64
    tex = np.zeros((1, 1, 2, 1), np.float32)
    uv = np.full((1, n, n, 2), 0.25, np.float32)     # texel (0, 0) of the 1 x 2 texture
    uv[0, :, n // 2:, 0] = 0.75                       # the right half reads texel (0, 1)
    rng = np.random.default_rng(31)
    g = (rng.uniform(-1, 1, size=(1, n, n, 1)) * 1e30).astype(np.float32)
    g[0, :, n // 2:] = np.abs(g[0, :, n // 2:])
    g[0, :, 3 * n // 4:] = -g[0, :, n // 2:3 * n // 4]   # texel (0, 1) sums to 0 exactly
    _, saved = texture_forward(tex, uv, filter_mode="nearest", boundary_mode="clamp",
                               dtype=np.float32, ctx=ctx)
    grad_tex = texture_backward(saved, g, deterministic=True)[0]
    left = g[0, :, :n // 2].astype(np.float64).sum()
    assert grad_tex[0, 0, 1, 0] == 0.0
    resolution = 2.0 ** -tx.fixed_point_shift(float(np.abs(g).max()), n * n)
    assert abs(grad_tex[0, 0, 0, 0] - left) <= U * abs(left) + n * n * resolution


def test_backward_uses_the_forwards_levels_only_while_they_are_current(ctx):
    """The backward reads the levels its forward left in the levels buffer (no second
    upload or pyramid build), and uploads and builds them again after another texture's
    forward replaced them: gradients equal in both orders, bit for bit."""
    mode = "linear-mipmap-linear"
    a = _f32(*make_inputs(51, "wrap", image=(16, 16), tex_size=(16, 16)))
    b = _f32(*make_inputs(52, "wrap", image=(16, 16), tex_size=(16, 16)))
    g = np.random.default_rng(53).normal(size=a[1].shape[:3] + (a[0].shape[-1],))
    g = g.astype(np.float32)
    _, saved_a = tx.forward(*a, filter_mode=mode, ctx=ctx)
    fresh = tx.backward(saved_a, g, deterministic=True)
    assert tx._HELD[ctx][0] is saved_a.uploaded         # read where the forward left them
    _, saved_b = tx.forward(*b, filter_mode=mode, ctx=ctx)
    assert tx._HELD[ctx][0] is saved_b.uploaded
    stale = tx.backward(saved_a, g, deterministic=True)  # b's levels there: a's again
    assert tx._HELD[ctx][0] is not saved_b.uploaded
    for x, y in zip(fresh[:4], stale[:4]):
        assert x.tobytes() == y.tobytes()
    other = tx.backward(saved_b, g, deterministic=True)
    assert other[0].tobytes() != fresh[0].tobytes()


@pytest.mark.parametrize("mode", ["nearest", "linear", "linear-mipmap-linear"])
def test_each_gradient_alone_is_the_one_of_the_full_backward(ctx, mode):
    """needs: tex alone (the shader without the coordinates' gradients) and the coordinates
    alone (without the texel sums) give the full backward's arrays, bit for bit
    (deterministic), None for the rest."""
    tex, uv, da, bias = _f32(*make_inputs(61, "wrap", image=(16, 16), tex_size=(8, 8)))
    if not mode.startswith("linear-mipmap"):
        da = bias = None
    out, saved = tx.forward(tex, uv, da, bias, filter_mode=mode, ctx=ctx)
    g = np.random.default_rng(62).normal(size=out[0].shape).astype(np.float32)
    full = tx.backward(saved, g, deterministic=True)
    texels = tx.backward(saved, g, needs=(True, False, False, False), deterministic=True)
    coords = tx.backward(saved, g, needs=(False, True, True, True), deterministic=True)
    assert texels[0].tobytes() == full[0].tobytes() and texels[1:] == (None,) * 3
    assert coords[0] is None
    for a, b in zip(coords[1:4], full[1:4]):
        assert (a is None and b is None) or a.tobytes() == b.tobytes()


def test_fixed_point_values_round_as_numpy_does(ctx):
    """The GPU's conversion of the 64-bit fixed-point sums to float32 gives the float of
    NumPy's int64 -> float64 -> ldexp -> float32, bit for bit: zero (llvmpipe's double
    ldexp(0, -k) is not 0, so the shader does not use it), both signs, values that round
    in float64 (above 2^53) and in float32, the ends of the range (|q| < 2^63 - 2^31 with
    the bias), a shift past float32's exponents."""
    rng = np.random.default_rng(41)
    q = np.concatenate([
        np.array([0, 1, -1, 2**31, -2**31, 2**32 - 1, 2**32, -2**32, 2**53 + 1, -(2**53) - 3,
                  2**62 - 1, -(2**62), 2**63 - 2**31 - 1, -(2**63)], np.int64),
        rng.integers(-2**62, 2**62, 5000, dtype=np.int64),
        rng.integers(-2**34, 2**34, 5001, dtype=np.int64)])
    padded = np.concatenate([q, np.full(-q.size % 4, 7, np.int64)])   # whole groups of 4
    for shift in (0, 38, 140, -20):
        with ctx:
            # stored plus the bias 2^31 (compute.fixed_point_clear's), as the backward adds
            words = ctx.storage_buffer("test.fixed_words",
                                       (padded + np.int64(bg.FIXED_BIAS)).view(np.uint32))
            out = tx.fixed_point_values(ctx, words, q.size, shift)
            got = np.frombuffer(out.read(size=4 * q.size), np.float32)
        want = np.ldexp(q.astype(np.float64), -shift).astype(np.float32)
        assert got.tobytes() == want.tobytes(), shift


@pytest.mark.parametrize("deterministic", [False, True])
@pytest.mark.parametrize("mode", ["linear-mipmap-nearest", "linear-mipmap-linear"])
def test_pull_back_from_the_highest_level_read_matches_the_reference(ctx, mode, deterministic):
    """Levels 0 .. 2 of a 7-level pyramid read (levels 0.1 .. 1.4 from the bias, so
    linear-mipmap-linear reads 0 .. 2, linear-mipmap-nearest 0 .. 1): the backward pulls the
    texel gradients back from the highest level read only, with the bound of every other
    mipmapped case."""
    rng = np.random.default_rng(32)
    tex = rng.normal(size=(1, 64, 64, 3))
    uv = rng.uniform(-0.2, 1.2, size=(1, 24, 24, 2))
    bias = rng.uniform(0.1, 1.4, size=(1, 24, 24))
    compare(ctx, tex, uv, None, bias, mode, "wrap", deterministic=deterministic)


def test_gpu_pyramid_matches_the_reference(ctx):
    rng = np.random.default_rng(29)
    for shape in [(1, 64, 48, 3), (2, 37, 50, 2), (1, 6, 9, 9, 4)]:
        tex = rng.normal(size=shape).astype(np.float32)
        boundary = "cube" if len(shape) == 5 else "wrap"
        gpu = tx.build_mips(tex, boundary_mode=boundary, ctx=ctx)
        ref = tr.build_mips(tex, ta.level_shapes(shape[-3], shape[-2]))
        assert len(gpu) == len(ref)
        for k, (a, b) in enumerate(zip(gpu, ref)):
            # k + 1 levels of 3 x 3 taps: (9 + 2) roundings per level on values <= max |tex|
            assert np.abs(a - b).max() <= 12 * (k + 1) * U * np.abs(tex).max(), (shape, k)


def test_bad_input_raises_before_the_gpu_runs(ctx):
    with pytest.raises(ValueError, match="uv must have shape"):
        texture_forward(np.zeros((1, 4, 4, 3)), np.zeros((1, 2, 2, 3)), dtype=np.float32,
                        ctx=ctx)
    _, saved = texture_forward(np.zeros((1, 4, 4, 3)), np.zeros((1, 2, 2, 2)),
                               dtype=np.float32, ctx=ctx)
    with pytest.raises(ValueError, match="grad_out must have shape"):
        texture_backward(saved, np.zeros((1, 2, 2, 4)))
    with pytest.raises(ValueError, match="accumulate must be one of"):
        texture_backward(saved, np.zeros((1, 2, 2, 3)), accumulate="sum")


def test_gl_sampler_matches_fetches_except_repeat_on_npot_textures(ctx):
    """The finding of docs/differentiable.md ("Could the GL sampler be used?"): with the
    level given explicitly (textureLod), llvmpipe's LINEAR_MIPMAP_LINEAR sampler agrees with
    the fetch-based filter within 2 ulp of the values for CLAMP_TO_EDGE, CLAMP_TO_BORDER and
    power-of-two REPEAT, but REPEAT on a non-power-of-two texture departs by more than the
    ten ulp (its wrapped coordinate is rounded differently), still inside the fetch path's
    own float32 bound."""
    if not ctx.is_llvmpipe:
        pytest.skip("the measured finding is llvmpipe's")
    rng = np.random.default_rng(30)
    uv = rng.uniform(-0.5, 1.5, size=(1, 64, 64, 2)).astype(np.float32)
    level = rng.uniform(0, 7, size=(1, 64, 64)).astype(np.float32)
    tex = rng.uniform(0, 1, size=(1, 64, 64, 4)).astype(np.float32)
    for boundary in ("wrap", "clamp", "zero"):
        sampled, fetched = tx.sampler_probe(tex, uv, level, boundary_mode=boundary, ctx=ctx)
        assert np.abs(sampled - fetched).max() <= 2 * 2.0 ** -23
    npot = rng.uniform(0, 1, size=(1, 37, 50, 4)).astype(np.float32)
    sampled, fetched = tx.sampler_probe(npot, uv, np.zeros_like(level), boundary_mode="wrap",
                                        ctx=ctx)
    X = 4 + np.abs(uv).max() * 50
    assert 10 * 2.0 ** -23 < np.abs(sampled - fetched).max() <= K * U * X
