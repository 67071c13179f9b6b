"""Multisample conformance: the probes name each multisampling mutant's defect in one line,
the goldens fold the sample axis into the width, and scenes run at every offered count."""

from __future__ import annotations

import numpy as np
import pytest

from glraster.conformance import check, golden, msaa_probes, mutants, probes
from glraster.conformance.scenes import list_scenes, load_scene, with_samples
from glraster.io import exr


def _multisampling(ctx):
    if 4 not in ctx.sample_counts:
        pytest.skip(f"{ctx.renderer} does not offer 4 samples")


@pytest.mark.parametrize("mutant, probe, words", [
    ("wrong_sample_position", "sample_perspective", "not taken at the sample positions"),
    ("centroid_as_center", "centroid", "outside the triangle"),
    ("sample_mask_ignored", "sample_positions", "but used at [0.5, 0.5]"),
    ("reversed_occlusion", "sample_depth", "keeps the wrong triangle"),
])
def test_each_multisample_mutant_fails_the_probe_that_names_it(ctx, mutant, probe, words):
    _multisampling(ctx)
    render = probes.mutant_render(mutants.get(mutant), ctx)
    result = dict(msaa_probes.PROBES)[probe](render, ctx)
    assert result.status == "fail", result.detail
    assert words in result.diagnosis, result.diagnosis
    assert "\n" not in result.diagnosis          # one line


def test_the_real_shaders_pass_the_probes_through_the_mutant_path(ctx):
    """The control: only the documented llvmpipe deviation is reported (no false alarm)."""
    _multisampling(ctx)
    render = probes.mutant_render(None, ctx)
    for name, probe in msaa_probes.PROBES:
        result = probe(render, ctx)
        allowed = ("pass", "known") if ctx.is_llvmpipe else ("pass",)
        assert result.status in allowed, (name, result.diagnosis)


def test_measured_sample_positions_equal_the_reported_ones(ctx):
    _multisampling(ctx)

    def render(pos, tri, resolution, outputs, **kw):
        from glraster.gpu.rasterize import rasterize
        return rasterize(pos, tri, resolution, ctx=ctx, outputs=outputs, **kw)
    for samples in [s for s in ctx.sample_counts if s > 1]:
        reported = msaa_probes.reported_positions(render, samples)
        measured = msaa_probes.measured_positions(render, samples)
        # 1/128 px: the measurement's step is 1/64 px
        assert np.abs(measured - reported).max() <= 1 / 128


def test_multisample_goldens_fold_the_sample_axis_into_the_width():
    for name in [n for n in list_scenes() if load_scene(n).samples > 1]:
        scene = load_scene(name)
        gold = exr.read_raster(golden.golden_path(name))
        h, w = scene.resolution
        assert gold.resolution == (h, w * scene.samples)
        assert gold.metadata["samples"] == str(scene.samples)
        assert gold.metadata["interpolation"] == scene.interpolation
        assert gold.metadata["layout"] == golden.LAYOUT
    scene = load_scene("ms_perspective_centroid")
    ref = golden.reference_for(scene)
    folded = golden.folded(ref, ("tri_id", "persp"))
    # column S x + s is sample s of pixel x; per-pixel values repeat on the S columns
    assert np.array_equal(folded["tri_id"][:, 4 * 10 + 2], ref.tri_id[:, 10, 2])
    assert np.array_equal(folded["persp"][:, 4 * 10 + 3], ref.persp[:, 10])


def test_multisample_goldens_match_the_reference_bit_for_bit():
    names = [n for n in list_scenes() if load_scene(n).samples > 1]
    results = golden.check(names)
    assert all(r.ok for r in results), [(r.name, r.message) for r in results if not r.ok]


def test_other_sample_counts_are_named_after_the_count():
    scene = load_scene("ms_fan_offcenter")
    assert with_samples(scene, 4) is scene
    other = with_samples(scene, 8)
    assert other.name == "ms_fan_offcenter@8x" and other.samples == 8


def test_reports_show_samples_and_interpolation(ctx, tmp_path):
    _multisampling(ctx)
    from glraster.conformance import junit
    result = check.run(ctx, ["basic_triangle", "ms_perspective_centroid"], probes=False)
    table = check.format_table(result)
    assert "4 centroid" in table and result.ok, table
    text = junit.to_string(result)
    assert 'name="samples" value="4"' in text
    assert 'name="interpolation" value="centroid"' in text
    assert "4 samples, interpolation centroid" in text
