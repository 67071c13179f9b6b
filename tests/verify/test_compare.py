"""compare(): counting mismatches and judging values against per-pixel tolerances."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import glraster as gr
from glraster.errors import ArgumentError
from glraster.geometry import synthetic
from glraster.verify.tolerance import EPS32, ErrorModel, value_tolerance


@pytest.fixture(scope="module")
def scene():
    pos, tri = synthetic.random_soup(60, seed=2)
    return pos, tri, gr.reference.rasterize(pos, tri, (96, 96))


def as_gpu(ref):
    """The reference rounded to float32, as a GPU raster would store it."""
    gpu = copy.copy(ref)
    gpu.persp = ref.persp.astype(np.float32)
    gpu.screen = ref.screen.astype(np.float32)
    gpu.depth = ref.depth.astype(np.float32)
    gpu.mask = ref.mask.copy()
    gpu.tri_id = ref.tri_id.copy()
    return gpu


def test_a_float32_copy_of_the_reference_passes(scene):
    _, _, ref = scene
    report = gr.compare(as_gpu(ref), ref)
    assert report.ok(), report.summary()
    assert report.coverage_mismatch == report.tri_id_mismatch == 0
    # Storing float32 rounds by at most half an ulp of values <= 1.
    assert report.values["persp"].max <= EPS32 / 2


def test_a_value_beyond_its_tolerance_fails(scene):
    _, _, ref = scene
    gpu = as_gpu(ref)
    tol = value_tolerance(ref.triangles, ref.tri_id, ("screen",)).screen
    ys, xs = np.nonzero(ref.mask & ~ref.depth_tie)
    y, x = ys[0], xs[0]
    gpu.screen[y, x, 1] += np.float32(3 * tol[y, x, 1])
    report = gr.compare(gpu, ref)
    assert not report.ok()
    assert report.values["screen"].over_tolerance == 1
    assert report.values["screen"].worst_ratio == pytest.approx(3, rel=0.01)
    assert report.maps.screen_ratio[y, x] == report.values["screen"].worst_ratio


def test_coverage_and_id_mismatches_are_counted(scene):
    _, _, ref = scene
    gpu = as_gpu(ref)
    empty = np.argwhere(~ref.mask)[0]
    gpu.mask[tuple(empty)] = True
    full = np.argwhere(ref.mask & ~ref.ambiguous)
    gpu.tri_id[tuple(full[0])] += 1
    report = gr.compare(gpu, ref)
    assert report.coverage_mismatch == 1
    assert report.tri_id_mismatch == 1
    assert not report.ok()
    assert "FAIL" in report.summary()


def test_mismatch_inside_the_edge_band_is_accepted(scene):
    pos, tri, _ = scene
    ref = gr.reference.rasterize(pos, tri, (96, 96), fill_rule=None)
    gpu = as_gpu(ref)
    band = np.argwhere(ref.edge_band)
    assert len(band)
    gpu.mask[tuple(band[0])] = not gpu.mask[tuple(band[0])]
    report = gr.compare(gpu, ref)
    assert report.coverage_mismatch == 0 and report.coverage_mismatch_in_band == 1


def test_tolerance_grows_with_distance_from_the_origin_and_the_center():
    # The same 6-px triangle at several places along a 4096-px viewport: plane equations
    # anchored at the origin lose eps32 |grad b| |v|, window positions x_ndc W/2 + W/2
    # lose eps32 |grad b| |v - center| (see glraster.tolerance).
    def tol_at(offset_px):
        res = (16, 4096)
        x = (np.array([offset_px + 2.3, offset_px + 8.1, offset_px + 3.7]) / 4096) * 2 - 1
        y = (np.array([2.2, 3.1, 9.4]) / 16) * 2 - 1
        pos = np.stack([x, y, np.zeros(3), np.ones(3)], 1).astype(np.float32)
        ref = gr.reference.rasterize(pos, [[0, 1, 2]], res)
        return value_tolerance(ref.triangles, ref.tri_id, ("screen",)).screen[ref.mask].max()
    center, far = tol_at(2045), tol_at(4000)
    assert far > 1.5 * center
    assert tol_at(0) > 0.9 * center     # the window-position term keeps the origin honest
    assert tol_at(3000) < far


def test_resolution_and_missing_ids_are_rejected(scene):
    _, _, ref = scene
    other = gr.reference.rasterize(np.zeros((3, 4)), [[0, 1, 2]], (8, 8))
    with pytest.raises(ValueError, match="same resolution"):
        gr.compare(other, ref)
    no_ids = gr.reference.rasterize(*scene[:2], (96, 96), outputs=("persp",))
    with pytest.raises(ValueError, match="ref must include the 'tri_id' output"):
        gr.compare(as_gpu(ref), no_ids)


def test_arguments_that_are_not_rasters_name_themselves(scene):
    """gpu and ref swapped, or None for one of them: an ArgumentError naming the argument,
    not an AttributeError from inside the comparison."""
    _, _, ref = scene
    gpu = gr.Raster(resolution=ref.resolution, mask=ref.mask.copy(),
                    tri_id=ref.tri_id.copy(), persp=ref.persp.astype(np.float32))
    for args, argument, got in (((gpu, None), "ref", "NoneType"),
                                ((None, ref), "gpu", "NoneType"),
                                ((ref, gpu), "ref", type(gpu).__name__)):
        with pytest.raises(ArgumentError) as err:
            gr.compare(*args)
        assert err.value.argument == argument and str(err.value).endswith(f"got {got}")


def test_generic_drivers_get_the_subpixel_term():
    class FakeContext:
        is_llvmpipe = False
        subpixel_bits = 8
    model = ErrorModel.for_context(FakeContext())
    assert model.position_error_px == 2.0**-8
    assert not model.waived_outputs


def test_nan_from_the_gpu_is_over_tolerance(scene):
    _, _, ref = scene
    gpu = as_gpu(ref)
    ys, xs = np.nonzero(ref.mask & ~ref.depth_tie)
    gpu.screen[ys[3], xs[3], 0] = np.nan
    report = gr.compare(gpu, ref)
    assert report.values["screen"].over_tolerance == 1
    assert not report.ok()
