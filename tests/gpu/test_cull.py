"""Culling at viewport sizes that are not powers of two, on near-degenerate triangles.

There the float32 viewport transform rounds, and a vertex lands on a different 1/256 px
fixed-point position depending on how it is computed. Culling must snap as the driver and
the reference do (glraster.geometry.window.window_float32, fused, then fill_rule.snap):
otherwise it drops slivers the driver draws, or keeps and drops back faces differently.
The scenes mix random triangles with slivers whose snapped doubled area is 0 or +-1
fixed-point unit, and with slivers built on vertices whose snapping the unfused transform
``(x_c * rcp) * W/2 + W/2`` gets wrong (so the tests fail for a culling that uses it).
"""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster.geometry import synthetic
from glraster.geometry.fill_rule import FIXED_ONE, snap
from glraster.geometry.window import window_float32
from glraster.gpu.cull import cull
from glraster.gpu.rasterize import CULL_MIN_TRIANGLES

# (height, width): 1000x750, 999x777, 1366x768
RESOLUTIONS = [(750, 1000), (777, 999), (768, 1366)]


def _unfused_window(pos, resolution):
    """The viewport transform rounded twice, (x_c * rcp) * W/2 + W/2 in float32: not what the
    driver computes; used only to build vertices on which it errs."""
    height, width = resolution
    rcp = np.float32(1.0) / pos[..., 3]
    half = np.array([width / 2, height / 2], np.float32)
    return (pos[..., :2] * rcp[..., None]) * half + half


def _fixed(pos, resolution):
    """(..., 2) int64 fixed-point window positions, as the driver snaps them."""
    return snap(window_float32(pos, resolution)).astype(np.int64)


def _fixed_area2(fixed, tri):
    a, b, c = fixed[tri[:, 0]], fixed[tri[:, 1]], fixed[tri[:, 2]]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])


def _clip_from_window(win, w, z_ndc, resolution):
    """float32 clip positions whose window position is about ``win`` (N, 2) px."""
    height, width = resolution
    ndc = np.asarray(win, np.float64) / np.array([width / 2, height / 2]) - 1
    return np.column_stack([ndc * w[:, None], z_ndc * w, w]).astype(np.float32)


def _fixed_slivers(rng, count, resolution):
    """Triangles built in fixed point with doubled area 0 (collinear) or +-1 unit (long
    slivers around a primitive direction d: cross(d, k d + e) = +-1), mapped to clip space;
    a few vertices land one unit off, which the caller measures."""
    height, width = resolution
    fixed = []
    for t in range(count):
        d = rng.integers(-6 * FIXED_ONE, 6 * FIXED_ONE, 2)
        g = np.gcd(*d)
        if g == 0:
            d = np.array([1, 1])
        elif t % 3:                       # area +-1: needs gcd(d) = 1
            d //= g
            if abs(d[1]) <= 1:
                d = np.array([d[0], d[1] or 1])
        a = np.array([rng.integers(24, width - 24), rng.integers(24, height - 24)]) * FIXED_ONE
        a += rng.integers(-FIXED_ONE, FIXED_ONE, 2)
        k = int(rng.integers(-2, 3))
        if t % 3 == 0:                    # collinear: area 0
            verts = [a, a + d, a + k * d]
        else:
            dx, dy = int(d[0]), int(d[1])
            m = abs(dy)
            ey = pow(dx % m, -1, m) if m > 1 else 0
            ex = (dx * ey - 1) // dy
            e = np.array([ex, ey]) * (1 if t % 3 == 1 else -1)   # cross(d, e) = +-1
            verts = [a, a + d, a + k * d + e]
        fixed.append(verts)
    fixed = np.array(fixed, np.float64)                           # (count, 3, 2)
    win = fixed.reshape(-1, 2) / FIXED_ONE + 0.5
    n = len(win)
    w = np.exp(rng.uniform(np.log(0.3), np.log(8.0), n))
    pos = _clip_from_window(win, w, rng.uniform(-0.9, 0.9, n), resolution)
    return pos, np.arange(n, dtype=np.int32).reshape(-1, 3)


def _boundary_slivers(rng, count, resolution, axis):
    """Slivers one fixed-point unit thick: two vertices on a sample row (axis 1) or column
    (axis 0), the third on a vertex that the unfused transform snaps onto that line and the
    fused one (the driver's) one unit above or to the right of it (drawn: the line is the
    bottom or left edge, whose samples are covered) or below or left of it (the line is a
    top or right edge, nothing is covered). Returns pos, tri and which are drawn. The
    unfused transform finds zero area on every one of them. (It never errs the other way
    here: where the two differ at a snapping boundary, the unfused sum is a float32 tie and
    rounds to the even grid value, which the fixed-point tie then snaps onto the line.)"""
    height, width = resolution
    size = (width, height)[axis]
    half = size / 2
    pos, kinds = [], []
    while len(kinds) < count:
        n = 4096
        line = rng.integers(8, size - 8, n)                       # sample row / column j
        w = np.exp(rng.uniform(np.log(0.3), np.log(8.0), n)).astype(np.float32)
        # vertices near the snapping boundary between units 256 j and 256 j +- 1
        boundary = line + 0.5 + rng.choice([-0.5, 0.5], n) / FIXED_ONE
        c0 = ((boundary / half - 1) * w).astype(np.float32)
        step = rng.integers(-24, 25, n)
        coord = c0 + step * np.spacing(np.abs(c0))
        probe = np.zeros((n, 4), np.float32)
        probe[:, axis] = coord
        probe[:, 3] = w
        fused = snap(window_float32(probe, resolution)[:, axis])
        unfused = snap(_unfused_window(probe, resolution)[:, axis])
        base = line * FIXED_ONE
        drawn = (fused == base + 1) & (unfused == base)
        under = (fused == base - 1) & (unfused == base)
        for i in np.flatnonzero(drawn | under)[: count - len(kinds)]:
            j = line[i]
            other = rng.integers(8, (height, width)[axis] - 12)    # along the line
            along = np.array([other + 0.2, other + 3.8, other + rng.uniform(0.5, 3.5)])
            wa = np.float32(rng.uniform(0.3, 8.0))
            win = np.zeros((3, 2))
            win[:, 1 - axis] = along
            win[:, axis] = j + 0.5                                # exactly on the line
            tri = _clip_from_window(win, np.array([wa, wa, w[i]]), rng.uniform(-0.9, 0.9, 3),
                                    resolution)
            tri[2, axis] = coord[i]                               # the boundary vertex
            if axis == 0:                     # keep counter-clockwise for a vertical line
                tri[[0, 1]] = tri[[1, 0]]
            on_line = snap(window_float32(tri[:2], resolution)[:, axis])
            if np.all(on_line == j * FIXED_ONE) and np.all(
                    snap(_unfused_window(tri[:2], resolution)[:, axis]) == j * FIXED_ONE):
                pos.append(tri)
                kinds.append(bool(drawn[i]))
    pos = np.concatenate(pos).astype(np.float32)
    return pos, np.arange(len(pos), dtype=np.int32).reshape(-1, 3), np.array(kinds)


def _scene(resolution, seed=0):
    """Random triangles, fixed-point slivers and boundary slivers, shuffled together.
    Returns pos, tri and the indices of the boundary slivers the driver draws."""
    rng = np.random.default_rng(seed)
    parts = [synthetic.random_soup(150, seed=seed), synthetic.random_soup(150, seed=seed + 1,
                                                                         size=0.002)]
    parts.append(_fixed_slivers(rng, 600, resolution))
    drawn = []
    for axis in (0, 1):
        pos, tri, kinds = _boundary_slivers(rng, 60, resolution, axis)
        parts.append((pos, tri))
        drawn.append(kinds)
    offsets = np.cumsum([0] + [len(p) for p, _ in parts])
    pos = np.concatenate([p for p, _ in parts])
    tri = np.concatenate([t + o for (_, t), o in zip(parts, offsets)])
    first_boundary = sum(len(t) for _, t in parts[:3])
    is_drawn_boundary = np.zeros(len(tri), bool)
    is_drawn_boundary[first_boundary:] = np.concatenate(drawn)
    order = rng.permutation(len(tri))
    return pos, tri[order], np.flatnonzero(is_drawn_boundary[order])


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_the_scenes_exercise_the_snapping(resolution):
    """Many triangles snap to area 0 and +-1, and on the boundary slivers the unfused
    transform decides zero area the other way round (the scene can catch it)."""
    pos, tri, drawn = _scene(resolution)
    area = _fixed_area2(_fixed(pos, resolution), tri)
    assert len(tri) >= CULL_MIN_TRIANGLES
    assert (area == 0).sum() >= 150 and (np.abs(area) == 1).sum() >= 300
    unfused = snap(_unfused_window(pos, resolution)).astype(np.int64)
    unfused_area = _fixed_area2(unfused, tri)
    assert (unfused_area[drawn] == 0).all() and (area[drawn] != 0).all()
    assert ((unfused_area == 0) != (area == 0)).sum() >= 2 * len(drawn)


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_culling_never_drops_a_triangle_the_driver_draws(ctx, resolution):
    """Triangle ids with and without host culling are the same image, bit for bit, and
    the driver does draw boundary slivers that an unfused transform would have culled."""
    pos, tri, drawn = _scene(resolution)
    a = gr.rasterize(pos, tri, resolution, ctx=ctx, outputs=("tri_id",), cull=True)
    b = gr.rasterize(pos, tri, resolution, ctx=ctx, outputs=("tri_id",), cull=False)
    assert a.info["culled"]["zero_area"] >= 150
    assert np.array_equal(a.tri_id, b.tri_id)
    if ctx.is_llvmpipe:
        # drawn alone, every boundary sliver covers samples (4 each); in the scene enough
        # of them stay visible that dropping them would change the image
        alone = gr.rasterize(pos, tri[drawn], resolution, ctx=ctx, outputs=("tri_id",))
        assert np.array_equal(np.unique(alone.tri_id[alone.mask]), np.arange(len(drawn)))
        assert np.isin(drawn, b.tri_id).sum() >= 10


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_culled_set_is_the_references_fixed_point_zero_area(resolution):
    """Inside the viewport, culling drops exactly the triangles whose fixed-point setup in
    the reference has zero area; everything it drops elsewhere is outside the view volume."""
    pos, tri, drawn = _scene(resolution)
    c = cull(pos, tri, resolution)
    s = gr.reference.setup(pos, tri, resolution, "llvmpipe")
    inside = s.exact
    assert inside.mean() > 0.9
    assert np.array_equal(~c.keep[inside], ~s.fixed_ok[inside])
    assert (s.culled | (s.planes_crossed > 0))[~c.keep].all()
    assert c.keep[drawn].all()
    assert c.reasons["zero_area"] == (~s.fixed_ok[inside]).sum()


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_host_dropped_back_faces_are_back_faces_for_the_driver(ctx, resolution):
    """Every triangle culled on the host as a back face is dropped by the driver's own face
    culling too (drawn in batches below CULL_MIN_TRIANGLES, so with GL_CULL_FACE only), and
    its fixed-point area is negative."""
    pos, tri, _ = _scene(resolution, seed=5)
    c = cull(pos, tri, resolution, backfaces=True)
    front = cull(pos, tri, resolution)
    back = np.flatnonzero(front.keep & ~c.keep)
    assert len(back) == c.reasons["backface"] > 100
    assert (_fixed_area2(_fixed(pos, resolution), tri[back]) < 0).all()
    batch = CULL_MIN_TRIANGLES - 1
    for start in range(0, len(back), batch):
        part = tri[back[start:start + batch]]
        r = gr.rasterize(pos, part, resolution, ctx=ctx, outputs=("tri_id",),
                         cull_backfaces=True)
        assert not r.info["culled"] and not r.mask.any()


@pytest.mark.parametrize("llvmpipe", [True, False])
def test_dropped_estimate_is_the_culls_fraction_on_its_sample(llvmpipe):
    """Every triangle sampled: the fraction cull drops (back faces kept); every 4th: the
    fraction among those triangles alone."""
    from glraster.gpu.cull import dropped_estimate

    resolution = (777, 999)
    pos, tri, _ = _scene(resolution, seed=3)     # slivers: zero area on llvmpipe
    pos = np.array(pos, np.float32)
    third = len(pos) // 3
    pos[:third, 0] += 2.5 * np.abs(pos[:third, 3])                  # some off-screen
    tri = np.concatenate([tri, tri[:50, [0, 0, 1]]]).astype(np.int32)  # repeated indices
    keep = cull(pos, tri, resolution, llvmpipe=llvmpipe).keep
    assert 0 < keep.mean() < 1
    for stride in (1, 4):
        sample = keep[::stride]
        assert dropped_estimate(pos, tri, resolution, llvmpipe=llvmpipe, stride=stride) \
            == (len(sample) - sample.sum()) / len(sample)
    assert dropped_estimate(pos, tri[:0], resolution) == 0.0
