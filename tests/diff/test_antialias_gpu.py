"""GPU antialias against the float64 reference: the pair records (which pairs blend, the
edge's vertices), the output, and both gradients within stated float32 bounds. Pairs with a
decision within the reference's band (antialias_reference.DECISION_BAND) are masked and
counted, never hidden."""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff import antialias as gaa
from glraster.diff import antialias_reference as aar
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from tests.diff.test_antialias_reference import (
    antialias_backward,
    antialias_forward,
    behind_scene,
    mesh_scene,
    soup_scene,
)

U = 2.0 ** -24
RES = (72, 96)


def render(ctx, pos, tri, colors, resolution=RES):
    """GPU rast and colour image (float32), as the float64 arrays the reference gets."""
    (rast, _), _ = RASTERIZE.forward(np.asarray(pos, np.float32), tri=tri,
                                     resolution=resolution, ctx=ctx)
    (col, _), _ = INTERPOLATE.forward(np.asarray(colors, np.float32), rast, tri=tri, ctx=ctx)
    return rast.astype(np.float64), col.astype(np.float64)


def scenes():
    m_pos, m_tri, m_col = mesh_scene(RES, level=3)
    t_pos, t_tri, t_col = mesh_scene(RES, level=2, eye=(2.4, 1.9, 1.1), fov=30.0, seed=4)
    s_pos, s_tri, s_col = soup_scene(RES, count=40, seed=7)
    b_pos, b_tri, b_col = behind_scene(RES)
    return {"icosphere": (m_pos, m_tri, m_col), "close_sphere": (t_pos, t_tri, t_col),
            "soup": (s_pos, s_tri, s_col), "behind_camera": (b_pos, b_tri, b_col)}


SCENES = scenes()


def gpu_antialias(*args, **kwargs):
    """The GPU core through ANTIALIAS.check (float32)."""
    return antialias_forward(*args, dtype=np.float32, **kwargs)


def reference_records(p: aar.Pairs, shape) -> np.ndarray:
    """(B, H, W, 2, 3) int64 (code, row_a, row_b) from the reference's pairs."""
    rec = np.zeros(tuple(shape[:3]) + (2, 3), np.int64)
    at_a = (p.modified == p.a_yx).all(-1)
    rec[p.batch, p.a_yx[:, 0], p.a_yx[:, 1], p.axis] = np.stack(
        [np.where(at_a, 1, 2), p.rows[:, 0], p.rows[:, 1]], -1)
    return rec


def out_bound(p: aar.Pairs, col, convex=True):
    """Per-pixel bound on |GPU - float64| of the output: each weight errs by the crossing's
    float32 error (8 u M(tau) + 4 u; twice that through the normalisation), the blend by
    8 u of the magnitudes it sums."""
    _, height, width, channels = col.shape
    flat = col.reshape(-1, channels)
    mod = (p.batch * height + p.modified[:, 0]) * width + p.modified[:, 1]
    par = (p.batch * height + p.partner[:, 0]) * width + p.partner[:, 1]
    dw = (8 * U * p.tau_mag + 4 * U) * (2 if convex else 1)
    bound = 8 * U * np.abs(flat)
    for c in range(channels):
        diff = np.abs(flat[par, c] - flat[mod, c])
        mag = np.abs(flat[par, c]) + np.abs(flat[mod, c])
        bound[:, c] += np.bincount(mod, weights=diff * dw + 8 * U * p.alpha * mag,
                                   minlength=len(flat))
    return bound.reshape(col.shape)


def test_records_equal_the_reference_outside_the_decision_band(ctx):
    for name, (pos, tri, colors) in SCENES.items():
        rast, col = render(ctx, pos, tri, colors)
        _, saved = antialias_forward(col, rast, pos, tri)
        p = saved.pairs
        want = reference_records(p, col.shape)
        got = gaa.pair_records(col, rast, pos, tri, ctx=ctx)[..., :3].astype(np.int64)
        differ = (got != want).any(-1)                      # (B, H, W, 2)
        amb = p.ambiguous
        mask = amb[..., None] | np.zeros_like(differ)
        # a record belongs to its pixel A; A or B of an ambiguous pair is flagged
        assert not (differ & ~mask).any(), (name, np.argwhere(differ & ~mask)[:5])
        assert len(p.tau) > 50, name
        assert amb.sum() <= 0.01 * amb.size, (name, int(amb.sum()))
        tau = got[..., 0] > 0
        gtau = gaa.pair_records(col, rast, pos, tri, ctx=ctx)[..., 3].view(np.float32)
        rtau = np.zeros(want.shape[:4])
        rtau[p.batch, p.a_yx[:, 0], p.a_yx[:, 1], p.axis] = p.tau
        rmag = np.zeros(want.shape[:4])
        rmag[p.batch, p.a_yx[:, 0], p.a_yx[:, 1], p.axis] = p.tau_mag
        ok = tau & ~mask
        assert (np.abs(gtau[ok] - rtau[ok]) <= 8 * U * rmag[ok] + 2 * U).all(), name


@pytest.mark.parametrize("convex", [True, False])
def test_output_within_the_float32_bound(ctx, convex):
    for name, (pos, tri, colors) in SCENES.items():
        rast, col = render(ctx, pos, tri, colors)
        ref_out, saved = antialias_forward(col, rast, pos, tri, convex=convex)
        out, _ = gpu_antialias(col, rast, pos, tri, ctx=ctx, convex=convex)
        p = saved.pairs
        keep = ~p.ambiguous
        err = np.abs(out - ref_out)
        bound = out_bound(p, col, convex)
        assert (err[keep] <= bound[keep]).all(), (name, (err / bound)[keep].max())
        assert np.abs(out - col).max() > 0.05, name


def gc_bound(p: aar.Pairs, col, g):
    """Per-pixel bound on the colour gradient: each weight's error (as in out_bound) times
    |g| of the blending pixel, at it and at its partner, plus 8 u of the terms summed."""
    _, height, width, channels = col.shape
    gf = np.abs(g.reshape(-1, channels))
    mod = (p.batch * height + p.modified[:, 0]) * width + p.modified[:, 1]
    par = (p.batch * height + p.partner[:, 0]) * width + p.partner[:, 1]
    dw = 2 * (8 * U * p.tau_mag + 4 * U) + 8 * U * p.alpha
    bound = 8 * U * gf
    for c in range(channels):
        bound[:, c] += np.bincount(mod, weights=dw * gf[mod, c], minlength=len(gf))
        bound[:, c] += np.bincount(par, weights=dw * gf[mod, c], minlength=len(gf))
    return bound.reshape(col.shape)


def upstream(p: aar.Pairs, shape, seed=0):
    """Random dL/d out, 0 on the pixels of ambiguous pairs."""
    g = np.random.default_rng(seed).normal(size=shape).astype(np.float32).astype(np.float64)
    g[p.ambiguous] = 0.0
    return g


@pytest.mark.parametrize("accumulate", gaa._gpu.FIXED_POINT_ACCUMULATIONS)
def test_gradients_within_the_float32_bound(ctx, accumulate):
    if accumulate == "atomic_float" and not gaa._gpu.has_atomic_float(ctx):
        pytest.skip("no GL_NV_shader_atomic_float")
    for name, (pos, tri, colors) in SCENES.items():
        rast, col = render(ctx, pos, tri, colors)
        _, saved = antialias_forward(col, rast, pos, tri)
        p = saved.pairs
        g = upstream(p, col.shape)
        ref_gc, ref_gp = antialias_backward(saved, g)
        _, gsaved = gpu_antialias(col, rast, pos, tri, ctx=ctx)
        gc, gp = antialias_backward(gsaved, g, accumulate=accumulate)
        # colour: the same weight errors as the output, times |g|
        bound = gc_bound(p, col, g) + 8 * U * np.abs(ref_gc)
        assert (np.abs(gc - ref_gc) <= bound + 1e-30).all(), name
        # positions: each term within 2^-14 of its magnitude (the crossing's conditioning
        # is in tau_mag), the float32 sum within n u of the summed magnitudes
        sign = np.where(p.tau < 0.5, -1.0, 1.0)
        terms = aar.crossing_gradients(pos, p.rows, p.a_yx, p.axis, RES, sign * np.ones_like(
            p.tau))
        mag_tau = np.abs(_dl_dalpha(saved, g))
        mag = np.zeros(ref_gp.reshape(-1, 4).shape)
        count = np.zeros(len(mag))
        for j in range(2):
            for c in (0, 1, 3):
                mag[:, c] += np.bincount(p.rows[:, j], weights=np.abs(terms[:, j, c]) * mag_tau,
                                         minlength=len(mag))
            count += np.bincount(p.rows[:, j], minlength=len(mag))
        bound = (2.0 ** -14 + count[:, None] * U) * mag
        err = np.abs(gp.reshape(-1, 4) - ref_gp.reshape(-1, 4))
        assert (err <= bound + 1e-30).all(), (name, (err / np.maximum(bound, 1e-30)).max())
        assert np.abs(ref_gp).max() > 0


def _dl_dalpha(saved, g):
    """A magnitude of dL/dalpha per pair: s sum_c |g_P| (|c_N| + |c_P|), twice that
    where the normalisation adds its term."""
    p, color = saved.pairs, saved.color
    batch, height, width, channels = color.shape
    pixels = batch * height * width
    mod, par, total, scale = aar._weights(p, pixels, height, width, saved.convex)
    flat, gf = color.reshape(pixels, channels), g.reshape(pixels, channels)
    delta = (np.abs(gf[mod]) * (np.abs(flat[par]) + np.abs(flat[mod]))).sum(-1)
    return scale[mod] * delta * np.where(total[mod] > 1, 2.0, 1.0)


def test_deterministic_backward_is_bit_identical(ctx):
    pos, tri, colors = SCENES["icosphere"]
    rast, col = render(ctx, pos, tri, colors)
    _, saved = gpu_antialias(col, rast, pos, tri, ctx=ctx)
    g = np.random.default_rng(3).normal(size=col.shape)
    runs = [antialias_backward(saved, g, deterministic=True) for _ in range(3)]
    for gc, gp in runs[1:]:
        assert np.array_equal(gc, runs[0][0]) and np.array_equal(gp, runs[0][1])


def test_batches_instanced_and_shared_pos(ctx):
    """(B, V, 4) pos draws each image with its own positions; (V, 4) pos is shared and its
    gradient sums the images'. Each image equals its single-image call."""
    pos0, tri, colors = mesh_scene(RES, level=2)
    pos1, _, _ = mesh_scene(RES, level=2, eye=(-0.6, 0.3, 2.9))
    r0, c0 = render(ctx, pos0, tri, colors)
    r1, c1 = render(ctx, pos1, tri, colors)
    rast, col = np.concatenate([r0, r1]), np.concatenate([c0, c1])
    g = np.random.default_rng(1).normal(size=col.shape)
    out, saved = gpu_antialias(col, rast, np.stack([pos0, pos1]), tri, ctx=ctx)
    o0, s0 = gpu_antialias(c0, r0, pos0, tri, ctx=ctx)
    o1, s1 = gpu_antialias(c1, r1, pos1, tri, ctx=ctx)
    np.testing.assert_array_equal(out, np.concatenate([o0, o1]))
    gc, gp = antialias_backward(saved, g, deterministic=True)
    gc0, gp0 = antialias_backward(s0, g[:1], deterministic=True)
    gc1, gp1 = antialias_backward(s1, g[1:], deterministic=True)
    np.testing.assert_array_equal(gc, np.concatenate([gc0, gc1]))
    np.testing.assert_allclose(gp, np.stack([gp0, gp1]), rtol=1e-6, atol=1e-6)
    # shared pos: both images drawn from pos0
    rast2, col2 = np.concatenate([r0, r0]), np.concatenate([c0, c0])
    _, ssaved = gpu_antialias(col2, rast2, pos0, tri, ctx=ctx)
    _, gps = antialias_backward(ssaved, np.concatenate([g[:1], g[:1]]), deterministic=True)
    np.testing.assert_allclose(gps, 2 * gp0, rtol=1e-6, atol=1e-5)


def test_pos_gradient_boost_and_welding_on_the_gpu(ctx):
    pos, tri, colors = SCENES["icosphere"]
    rast, col = render(ctx, pos, tri, colors)
    g = np.random.default_rng(2).normal(size=col.shape)
    _, s1 = gpu_antialias(col, rast, pos, tri, ctx=ctx)
    _, s4 = gpu_antialias(col, rast, pos, tri, ctx=ctx, pos_gradient_boost=4.0)
    _, p1 = antialias_backward(s1, g, deterministic=True)
    _, p4 = antialias_backward(s4, g, deterministic=True)
    np.testing.assert_allclose(p4, 4 * p1, rtol=1e-6)
    split_pos = pos[tri.ravel()]
    split_tri = np.arange(tri.size).reshape(-1, 3).astype(np.int32)
    welded = gaa.antialias_construct_topology_hash(split_tri, pos=split_pos)
    out, _ = gpu_antialias(col, rast, pos, tri, ctx=ctx)
    out_w, _ = gpu_antialias(col, rast, split_pos, split_tri, welded, ctx=ctx)
    out_s, _ = gpu_antialias(col, rast, split_pos, split_tri, ctx=ctx)
    np.testing.assert_array_equal(out_w, out)
    assert np.abs(out_s - out).max() > 0.05


def test_gpu_bad_input(ctx):
    pos, tri, colors = SCENES["soup"]
    rast, col = render(ctx, pos, tri, colors)
    with pytest.raises(ValueError, match="color must have shape"):
        gpu_antialias(col[..., :0], rast, pos, tri, ctx=ctx)
    with pytest.raises(ValueError, match="topology_hash was built for a different tri"):
        gpu_antialias(col, rast, pos, tri, gaa.antialias_construct_topology_hash(tri[1:]),
                      ctx=ctx)
    _, saved = gpu_antialias(col, rast, pos, tri, ctx=ctx)
    with pytest.raises(ValueError, match="grad_out must have shape"):
        antialias_backward(saved, col[:, 1:])
    with pytest.raises(ValueError, match="accumulate must be one of"):
        antialias_backward(saved, col, accumulate="sum")


@pytest.mark.parametrize("name", ["icosphere", "soup"])
def test_records_the_pairs_pass_leaves_unwritten_are_never_read(ctx, name):
    """Pass 1 writes the records of the listed pairs only and nobody clears the rest: the
    output and both gradients are the same bits whether the records buffer held zeros or
    garbage (random codes, rows and taus) before the call."""
    pos, tri, colors = SCENES[name]
    rast, col = render(ctx, pos, tri, colors)
    g = np.random.default_rng(3).standard_normal(col.shape).astype(np.float32)
    results = []
    for fill in ("zeros", "garbage"):
        with ctx:
            records = ctx.scratch_buffer("antialias.records", rast[..., 0].size * 32)
            garbage = np.random.default_rng(1).integers(0, 2 ** 32, records.size // 4,
                                                        dtype=np.uint32)
            records.write((garbage if fill == "garbage" else 0 * garbage).tobytes())
        out, saved = gpu_antialias(col, rast, pos, tri, ctx=ctx)
        results.append((out, *antialias_backward(saved, g, deterministic=True)))
    for zeros, garbage in zip(*results):
        assert zeros.tobytes() == garbage.tobytes()
