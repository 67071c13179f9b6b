"""The reference's multisampling: per-sample coverage with the fixed-point rule, per-sample
depth, centroid points, and validation of samples / sample_positions (no GL)."""

from __future__ import annotations

import numpy as np
import pytest

from glraster import reference
from glraster.geometry.samples import fixed_offsets, standard_positions
from glraster.geometry.window import window_float32

POS = np.array([[-0.83, -0.71, 0.1, 1], [0.77, -0.2, 0.5, 1], [-0.1, 0.93, -0.3, 1]],
               np.float32)


def test_each_sample_is_the_fixed_point_rule_at_its_position():
    """Per-sample coverage equals a brute-force evaluation of llvmpipe's edge test at the
    fixed-point point (256 x + dx, 256 y + dy) of every sample (exact integers)."""
    positions = standard_positions(4)
    ref = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=4, outputs=("tri_id",))
    edges, ok = reference.fixed_edges(window_float32(POS[None], (20, 24)))
    dcdx, dcdy, c = edges[0, :, 0], edges[0, :, 1], edges[0, :, 2]
    offsets = fixed_offsets(positions, 256)
    ys, xs = np.mgrid[0:20, 0:24]
    for s, (dx, dy) in enumerate(offsets):
        x = 256 * xs[..., None] + dx
        y = 256 * ys[..., None] + dy
        inside = (c - dcdx * x + dcdy * y >= 1).all(axis=-1)
        assert np.array_equal(ref.mask[..., s], inside)


def test_per_sample_depth_is_the_depth_plane_at_the_sample():
    ref = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=4)
    ts = ref.triangles
    plane = 0.5 * np.einsum("i,ij->j", ts.clip[0, :, 2], ts.adj[0]) / ts.det[0]
    plane[2] += 0.5
    ys, xs = np.mgrid[0:20, 0:24]
    for s, (ox, oy) in enumerate(ref.sample_positions):
        expected = plane[0] * (xs + ox) + plane[1] * (ys + oy) + plane[2]
        m = ref.mask[..., s]
        # 1e-15: float64 plane evaluated in another order
        assert np.abs(ref.depth[..., s][m] - expected[m]).max() < 1e-15


def test_one_sample_at_the_center_is_the_single_sample_reference():
    a = reference.rasterize(POS, [[0, 1, 2]], (20, 24))
    assert a.samples == 1 and a.mask.shape == (20, 24)


def test_coverage_is_the_covered_fraction():
    ref = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=4)
    assert np.array_equal(ref.coverage, ref.mask.sum(axis=2) / np.float32(4))
    assert ((ref.coverage > 0) & (ref.coverage < 1)).any()


def test_centroid_point_is_inside_pixel_and_triangle():
    """The reference's centroid: the center where all samples are covered, else the first
    covered sample; its screen barycentrics are then all >= 0 (inside the triangle)."""
    ref = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=4, interpolation="centroid",
                              outputs=("screen", "tri_id"))
    center = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=4, outputs=("screen",))
    full = ref.mask.all(axis=2)
    partial = ref.mask.any(axis=2) & ~full
    assert np.array_equal(ref.screen[full], center.screen[full])
    assert (ref.screen[partial] >= -1e-12).all()
    assert not np.allclose(ref.screen[partial], center.screen[partial])


def test_sample_interpolation_has_a_value_per_sample():
    ref = reference.rasterize(POS, [[0, 1, 2]], (8, 8), samples=2, interpolation="sample")
    assert ref.persp.shape == (8, 8, 2, 3)
    covered = ref.mask
    assert np.allclose(ref.persp[covered].sum(axis=-1), 1)


def test_positions_off_the_fixed_point_grid_fall_back_to_the_edge_band():
    positions = [[0.3, 0.3], [0.7, 0.7]]          # not whole 1/256 steps
    ref = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=2,
                              sample_positions=positions, outputs=("tri_id",))
    assert ref.edge_band.any()
    grid = reference.rasterize(POS, [[0, 1, 2]], (20, 24), samples=2, outputs=("tri_id",))
    assert not grid.edge_band.any()


@pytest.mark.parametrize("kwargs, message", [
    ({"samples": 3}, "samples must be a power of two"),
    ({"samples": 0}, "samples must be a power of two"),
    ({"samples": 4, "sample_positions": [[0.5, 0.5]]}, r"sample_positions must have shape \(4, 2\)"),
    ({"samples": 2, "sample_positions": [[0.5, 1.5], [0.1, 0.1]]}, "inside the pixel"),
    ({"samples": 32}, "no standard sample pattern"),
    ({"interpolation": "pixel"}, "interpolation must be one of"),
])
def test_bad_arguments_are_value_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        reference.rasterize(POS, [[0, 1, 2]], (4, 4), **kwargs)
