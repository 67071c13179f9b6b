"""Comparing multisampled rasters: per-sample judging and the point check of "center" /
"centroid" barycentrics (no GL: the 'GPU' side is the reference rounded to float32)."""

from __future__ import annotations

import numpy as np
import pytest

from glraster import compare, reference
from glraster.types import Raster

POS = np.array([[-0.83, -0.71, 0.1, 1], [0.77 * 3, -0.2 * 3, 0.5 * 3, 3],
                [-0.1, 0.93, -0.3, 1], [-1, -1, 0.9, 1], [1, -1, 0.9, 1], [0, 1, 0.9, 1]],
               np.float32)
TRI = [[0, 1, 2], [3, 4, 5]]


def _as_gpu(ref) -> Raster:
    """The reference as a float32 GPU raster (values exact to float32 rounding)."""
    out = {n: getattr(ref, n).astype(np.float32) for n in ("persp", "screen", "depth")}
    return Raster(resolution=ref.resolution, mask=ref.mask.copy(), tri_id=ref.tri_id.copy(),
                  samples=ref.samples, interpolation=ref.interpolation,
                  sample_positions=ref.sample_positions, **out)


@pytest.mark.parametrize("interpolation", ["center", "centroid", "sample"])
def test_the_reference_in_float32_passes(interpolation):
    ref = reference.rasterize(POS, TRI, (24, 32), samples=4, interpolation=interpolation)
    rep = compare(_as_gpu(ref), ref)
    assert rep.ok(), rep.summary()
    assert rep.samples == 4 and rep.interpolation == interpolation
    assert (rep.point is None) == (interpolation == "sample")


def test_one_wrong_sample_id_is_counted():
    ref = reference.rasterize(POS, TRI, (24, 32), samples=4)
    gpu = _as_gpu(ref)
    y, x = np.argwhere(ref.mask[..., 2] & ~ref.ambiguous[..., 2])[0]
    gpu.tri_id[y, x, 2] = 1 - gpu.tri_id[y, x, 2]
    rep = compare(gpu, ref)
    assert rep.tri_id_mismatch == 1 and not rep.ok()


def test_values_at_the_wrong_sample_fail():
    """Per-sample values swapped between two samples: over tolerance."""
    ref = reference.rasterize(POS, TRI, (24, 32), samples=4, interpolation="sample")
    gpu = _as_gpu(ref)
    gpu.persp = np.ascontiguousarray(gpu.persp[:, :, [1, 0, 2, 3]])
    rep = compare(gpu, ref)
    assert rep.values["persp"].over_tolerance > 0


def test_centroid_taken_at_the_center_fails_only_where_the_center_is_outside():
    """The point check: values of the pixel center pass for "center" and fail "centroid"
    only on partly covered pixels whose center is outside the triangle."""
    center = reference.rasterize(POS, TRI, (24, 32), samples=4, interpolation="center")
    centroid = reference.rasterize(POS, TRI, (24, 32), samples=4, interpolation="centroid")
    gpu = _as_gpu(center)
    gpu.interpolation = "centroid"
    rep = compare(gpu, centroid)
    assert rep.point.outside_triangle > 0 and not rep.ok()
    assert rep.point.outside_pixel == 0


def test_persp_divided_by_one_over_w_at_another_point_is_named():
    """A driver that interpolates b_i / w_i at the sample but 1 / w at the pixel center:
    the point check reports persp not perspective-correct at the implied point."""
    ref = reference.rasterize(POS, TRI, (24, 32), samples=4, interpolation="centroid")
    gpu = _as_gpu(ref)
    ts = ref.triangles
    ys, xs = np.nonzero(ref.mask.any(axis=2))
    t = np.array([ref.tri_id[y, x][ref.mask[y, x]][0] for y, x in zip(ys, xs)])
    w = ts.clip[t, :, 3]
    s_point = ref.screen[ys, xs] / w                     # s_i = b_i / w_i at the point
    a = ts.adj[t]
    s_center = (a[..., 0] * (xs + 0.5)[:, None] + a[..., 1] * (ys + 0.5)[:, None]
                + a[..., 2]) / ts.det[t][:, None]
    wrong = gpu.persp.copy()
    wrong[ys, xs] = (s_point / s_center.sum(axis=1)[:, None]).astype(np.float32)
    gpu.persp = wrong
    rep = compare(gpu, ref)
    assert rep.point.persp_inconsistent > 0


def test_mismatched_samples_are_value_errors():
    ref4 = reference.rasterize(POS, TRI, (8, 8), samples=4)
    ref2 = reference.rasterize(POS, TRI, (8, 8), samples=2)
    with pytest.raises(ValueError, match="same samples per pixel"):
        compare(_as_gpu(ref2), ref4)
    sample = reference.rasterize(POS, TRI, (8, 8), samples=4, interpolation="sample")
    with pytest.raises(ValueError, match="same interpolation"):
        compare(_as_gpu(sample), ref4)
