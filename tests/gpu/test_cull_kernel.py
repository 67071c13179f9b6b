"""The compiled culling (glraster.gpu.cull_kernel) against its NumPy formulation,
triangle by triangle and reason by reason, on the scenes of tests/gpu/test_cull.py
(slivers of zero and unit fixed-point area, vertices on snapping boundaries) and on random
meshes around and behind the eye, with and without back-face culling, for llvmpipe's rules
and the others'."""

from __future__ import annotations

import numpy as np
import pytest

from glraster.gpu.cull import BACKFACE_MARGIN_PX2, cull, window_fixed
from tests.gpu.test_cull import RESOLUTIONS, _boundary_slivers, _fixed_slivers


def _area2(x, y, tri):
    """Twice the signed window area (T,) of triangles ``tri`` (T, 3) over per-vertex x, y."""
    x0, x1, x2 = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    y0, y1, y2 = y[tri[:, 0]], y[tri[:, 1]], y[tri[:, 2]]
    return (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)



def _numpy_cull(pos, tri, resolution, backfaces, llvmpipe, subpixel_bits=8):
    """(keep, reasons) as the NumPy formulation computes them."""
    height, width = resolution
    x, y, z, w = pos[:, 0], pos[:, 1], pos[:, 2], pos[:, 3]
    # Cohen-Sutherland style outcodes per vertex; a triangle is outside when its three
    # vertices share a bit (GL 4.5 core section 13.7: all outside one clip plane).
    code = (
        (x > w).view(np.uint8) | ((x < -w).view(np.uint8) << 1)
        | ((y > w).view(np.uint8) << 2) | ((y < -w).view(np.uint8) << 3)
        | ((z > w).view(np.uint8) << 4) | ((z < -w).view(np.uint8) << 5)
    )
    i0, i1, i2 = tri[:, 0], tri[:, 1], tri[:, 2]
    outside = (code[i0] & code[i1] & code[i2]) != 0
    keep = ~outside
    reasons = {"outside": int(outside.sum()), "zero_area": 0, "backface": 0}
    if not llvmpipe:
        same = (i0 == i1) | (i1 == i2) | (i2 == i0)
        reasons["zero_area"] = int((same & keep).sum())
        keep &= ~same

    if llvmpipe or backfaces:
        # the driver's window positions and fixed-point vertices, the very transform and
        # snapping of the reference (glraster.geometry.window, fill_rule)
        wx, wy, sx, sy = window_fixed(pos, resolution, subpixel_bits)
        limit = np.float32(1 << 22)
        with np.errstate(invalid="ignore"):
            front_v = (w > 0) & (np.abs(z) <= w)
            bounded_v = front_v & (np.abs(wx) < limit) & (np.abs(wy) < limit)
        # Snapped coordinates are integers below 2^30, held exactly in float64; for
        # triangles inside the viewport (|X| < 2^22) the area products stay below 2^46
        # and are exact, which is where the zero test is used.
        fx = np.where(bounded_v, sx, 0).astype(np.float64)
        fy = np.where(bounded_v, sy, 0).astype(np.float64)
        bounded = bounded_v[i0] & bounded_v[i1] & bounded_v[i2]
        area = _area2(fx, fy, tri)
        if llvmpipe:
            inside_v = bounded_v & (wx >= 0) & (wx <= width) & (wy >= 0) & (wy <= height)
            flat = inside_v[i0] & inside_v[i1] & inside_v[i2] & (area == 0) & keep
            reasons["zero_area"] = int(flat.sum())
            keep &= ~flat
        if backfaces:
            area_f = _area2(wx.astype(np.float64), wy.astype(np.float64), tri)
            back = bounded & (area < 0) & (area_f < -BACKFACE_MARGIN_PX2) & keep
            reasons["backface"] = int(back.sum())
            keep &= ~back
    return keep, reasons


def _random_mesh(rng, resolution, n=3000):
    """Vertices in, around and behind the view volume (some w <= 0, some repeated, some on
    the near and far planes), random triangles over them (repeated indices included)."""
    w = rng.uniform(-0.5, 4.0, n)
    xyz = rng.uniform(-1.6, 1.6, (n, 3)) * np.abs(w)[:, None]
    pos = np.column_stack([xyz, w]).astype(np.float32)
    pos[::17] = pos[1::17][: len(pos[::17])]
    pos[5::31, 2] = pos[5::31, 3]                 # on the far and near planes: |z| = w
    pos[7::37, 2] = -pos[7::37, 3]
    tri = rng.integers(0, n, (2 * n, 3)).astype(np.int32)
    tri[::13, 2] = tri[::13, 0]
    return pos, tri


def _scenes(resolution):
    rng = np.random.default_rng(resolution[1])
    yield _random_mesh(rng, resolution)
    if min(resolution) < 64:          # the slivers need room inside the viewport
        return
    yield _fixed_slivers(rng, 300, resolution)
    pos, tri, _ = _boundary_slivers(rng, 40, resolution, 0)
    yield pos, tri


@pytest.mark.parametrize("resolution", RESOLUTIONS + [(4, 4)])
@pytest.mark.parametrize("backfaces", [False, True])
@pytest.mark.parametrize("llvmpipe", [True, False])
def test_culling_equals_the_numpy_formulation(resolution, backfaces, llvmpipe):
    for pos, tri in _scenes(resolution):
        keep, reasons = _numpy_cull(pos, tri, resolution, backfaces, llvmpipe)
        got = cull(pos, tri, resolution, backfaces=backfaces, llvmpipe=llvmpipe)
        assert np.array_equal(got.keep, keep)
        assert got.reasons == reasons
        assert np.array_equal(got.kept, np.flatnonzero(keep))


def test_every_reason_is_exercised():
    """The scenes drop triangles for each reason (else the test above proves less)."""
    seen = {"outside": 0, "zero_area": 0, "backface": 0}
    for pos, tri in _scenes(RESOLUTIONS[0]):
        for reason, count in cull(pos, tri, RESOLUTIONS[0], backfaces=True).reasons.items():
            seen[reason] += count
    assert min(seen.values()) > 10, seen
