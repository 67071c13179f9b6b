"""Multisampled rasterization on the GPU: shapes, sample positions, exact readback, the
per-sample reference, and the errors for what the driver or the method does not offer."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster import reference
from glraster.geometry.window import clip_to_window
from glraster.types import first_covered_sample, per_pixel


def _random_scene(seed, count=40):
    """``count`` random triangles, some perspective, some crossing the viewport edges."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1.1, 1.1, (3 * count, 4)).astype(np.float32)
    pos[:, 3] = rng.uniform(0.5, 2.0, 3 * count)
    pos[:, :2] *= pos[:, 3:4]
    pos[:, 2] = rng.uniform(-0.9, 0.9, 3 * count) * pos[:, 3]
    return pos, np.arange(3 * count).reshape(count, 3)


def _samples(ctx):
    counts = [s for s in ctx.sample_counts if s > 1]
    if not counts:
        pytest.skip(f"{ctx.renderer} offers no multisampling")
    return counts


FULL = np.array([[-1, -1, 0.2, 1], [3, -1, 0.2, 1], [-1, 3, 0.2, 1]], np.float32)


def test_samples_one_is_the_single_sample_path_bit_for_bit(ctx):
    pos, tri = _random_scene(3)
    a = gr.rasterize(pos, tri, (40, 56), ctx=ctx)
    b = gr.rasterize(pos, tri, (40, 56), ctx=ctx, samples=1, interpolation="sample")
    for name in ("persp", "screen", "depth", "tri_id", "mask"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.samples == 1 and a.sample_positions.tolist() == [[0.5, 0.5]]
    assert a.coverage.dtype == np.float32 and a.coverage.shape == (40, 56)


@pytest.mark.parametrize("interpolation", ["center", "centroid", "sample"])
def test_per_sample_arrays_have_a_sample_axis_after_w(ctx, interpolation):
    for samples in _samples(ctx):
        r = gr.rasterize(FULL, [[0, 1, 2]], (6, 10), ctx=ctx, samples=samples,
                         interpolation=interpolation)
        assert r.tri_id.shape == r.depth.shape == r.mask.shape == (6, 10, samples)
        assert r.tri_id.dtype == np.int32 and r.depth.dtype == np.float32
        bary = (6, 10, samples, 3) if interpolation == "sample" else (6, 10, 3)
        assert r.persp.shape == r.screen.shape == bary
        assert r.coverage.shape == (6, 10) and (r.coverage == 1).all()
        assert r.sample_positions.shape == (samples, 2)
        assert r.samples == samples and r.interpolation == interpolation


def test_sample_positions_are_inside_the_pixel_and_distinct(ctx):
    for samples in _samples(ctx):
        p = gr.rasterize(FULL, [[0, 1, 2]], (2, 2), ctx=ctx, samples=samples).sample_positions
        assert ((p >= 0) & (p < 1)).all()
        assert len({tuple(x) for x in p.tolist()}) == samples


def test_screen_values_per_sample_are_taken_at_the_reported_positions(ctx):
    """On an affine triangle the window-space barycentrics give back the point they were
    evaluated at: with interpolation="sample" that is each reported sample position.
    Tolerance 1e-5 px: float32 barycentrics of a triangle 4 viewports wide."""
    for samples in _samples(ctx):
        r = gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=samples,
                         interpolation="sample", outputs=("screen",))
        win = clip_to_window(FULL, (4, 4))[:, :2].astype(np.float64)
        point = r.screen.astype(np.float64) @ win                 # (H, W, S, 2)
        ys, xs = np.mgrid[0:4, 0:4]
        offset = point - np.stack([xs, ys], -1)[:, :, None, :]
        assert np.abs(offset - r.sample_positions).max() < 1e-5


def test_per_sample_ids_match_the_reference_exactly_on_llvmpipe(ctx):
    """The reference evaluates llvmpipe's fixed-point rule at each sample: ids agree on
    every sample outside the ambiguous ones (clipped triangles' edge band, depth ties)."""
    if not ctx.is_llvmpipe:
        pytest.skip("the fixed-point model is llvmpipe's")
    for seed in range(3):
        pos, tri = _random_scene(seed)
        r = gr.rasterize(pos, tri, (48, 40), ctx=ctx, samples=4, outputs=("tri_id", "depth"))
        ref = reference.rasterize(pos, tri, (48, 40), samples=4, outputs=("tri_id", "depth"),
                                  sample_positions=r.sample_positions)
        judged = ~ref.ambiguous
        assert judged.mean() > 0.9
        assert np.array_equal(r.tri_id[judged], ref.tri_id[judged])
        both = judged & r.mask
        # depth: float32 plane equations, well below the tie threshold (2^-17)
        assert np.abs(r.depth[both] - ref.depth[both]).max() < 2.0**-17


def test_center_interpolation_matches_the_reference_at_the_pixel_center(ctx):
    """"center": one value per pixel, the fragment of the first covered sample, at the
    pixel center. Tolerance 2e-4: the driver's float32 error on random triangles (the
    per-pixel error model bounds it per pixel in the conformance checks)."""
    _samples(ctx)
    pos, tri = _random_scene(5)
    samples = ctx.sample_counts[-1]
    r = gr.rasterize(pos, tri, (48, 40), ctx=ctx, samples=samples, outputs=("persp", "tri_id"))
    ref = reference.rasterize(pos, tri, (48, 40), samples=samples, outputs=("persp", "tri_id"),
                              sample_positions=r.sample_positions)
    first = first_covered_sample(r.mask)
    same = (per_pixel(r.tri_id, first) == per_pixel(ref.tri_id, first)) & r.mask.any(axis=2) \
        & ~ref.ambiguous.any(axis=2)
    assert same.sum() > 500
    assert np.abs(r.persp[same] - ref.persp[same]).max() < 2e-4


def test_the_readback_is_exact_not_averaged(ctx):
    """Two triangles meeting inside pixels: every sample holds one triangle's id, never a
    blend, and partly covered pixels have fractional coverage."""
    for samples in _samples(ctx):
        pos = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [-0.9, 1, 0, 1], [1, 1, 0, 1]],
                       np.float32)
        r = gr.rasterize(pos, [[0, 1, 2], [1, 3, 2]], (16, 16), ctx=ctx, samples=samples)
        assert set(np.unique(r.tri_id).tolist()) <= {-1, 0, 1}
        mixed = (r.tri_id == 0).any(axis=2) & (r.tri_id == 1).any(axis=2)
        assert mixed.any()
        assert ((r.coverage > 0) & (r.coverage < 1)).any()


@pytest.mark.parametrize("method", ["divw", "homogeneous", "solve4"])
def test_other_methods_multisample_at_the_center(ctx, method):
    """Coverage, ids and depth come from the driver for every method; the barycentrics at
    the center agree with method "hw" (within 1e-4: different float32 formulations)."""
    if gr.gpu.methods.available(ctx)[method] is None:
        pytest.skip(f"{method} needs OpenGL 4.5")
    samples = _samples(ctx)[-1]
    pos, tri = _random_scene(8, 20)
    hw = gr.rasterize(pos, tri, (32, 32), ctx=ctx, samples=samples)
    other = gr.rasterize(pos, tri, (32, 32), ctx=ctx, samples=samples, method=method)
    assert np.array_equal(hw.tri_id, other.tri_id)
    both = hw.mask.any(axis=2)
    assert np.abs(hw.persp[both] - other.persp[both]).max() < 1e-4


def test_bad_samples_and_interpolation_are_value_errors(ctx):
    with pytest.raises(ValueError, match="samples must be a power of two"):
        gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=3)
    with pytest.raises(ValueError, match="samples must be a power of two"):
        gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=True)
    with pytest.raises(ValueError, match="is not offered by this driver"):
        gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=1024)
    with pytest.raises(ValueError, match="interpolation must be one of"):
        gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, interpolation="middle")
    samples = _samples(ctx)[-1]
    if gr.gpu.methods.available(ctx)["solve4"] is not None:
        with pytest.raises(ValueError, match="offers interpolation"):
            gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=samples,
                         method="solve4", interpolation="sample")
    with pytest.raises(ValueError, match="out is only supported with samples=1"):
        r = gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx)
        gr.rasterize(FULL, [[0, 1, 2]], (4, 4), ctx=ctx, samples=samples, out=r)
    with pytest.raises(ValueError, match="wide, above the driver's limit"):
        gr.rasterize(FULL, [[0, 1, 2]], (2, ctx.max_texture_size), ctx=ctx, samples=samples,
                     outputs=("tri_id",))


def test_gl33_path_multisamples_too(gl_backend):
    """The vertex-attribute path (GL 3.3 shaders) gives the same per-sample results."""
    ctx33 = gr.Context(gl_backend, max_gl=33)
    try:
        if len(ctx33.sample_counts) < 2:
            pytest.skip("no multisampling")
        samples = ctx33.sample_counts[-1]
        full = gr.Context(gl_backend)
        pos, tri = _random_scene(11, 20)
        for interpolation in ("center", "centroid", "sample"):
            a = gr.rasterize(pos, tri, (24, 24), ctx=ctx33, samples=samples,
                             interpolation=interpolation)
            b = gr.rasterize(pos, tri, (24, 24), ctx=full, samples=samples,
                             interpolation=interpolation)
            assert np.array_equal(a.tri_id, b.tri_id)
            assert np.array_equal(a.persp, b.persp), interpolation
        full.release()
    finally:
        ctx33.release()
