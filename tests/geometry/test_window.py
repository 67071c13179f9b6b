"""The viewport transform as the driver computes it, and the one snapping to fixed point.

GPU-side culling and the reference must land every vertex on the same 1/256 px position as
the driver: window_float32 rounds the last step (scale * ndc + scale) once, like llvmpipe's
fused multiply-add; the unfused form rounds twice and snaps differently at widths and
heights that are not powers of two.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from glraster.geometry import synthetic
from glraster.geometry.fill_rule import FIXED_ONE, snap
from glraster.geometry.window import window_float32, window_xy_float32
from glraster.gpu.cull import window_fixed

# (height, width): 1000x750, 999x777, 1366x768
RESOLUTIONS = [(750, 1000), (777, 999), (768, 1366)]


def _round_to_float32(q: Fraction) -> float:
    """q rounded once to the nearest float32, ties to even (normal range only)."""
    if q == 0:
        return 0.0
    sign, q = (-1 if q < 0 else 1), abs(q)
    e = q.numerator.bit_length() - q.denominator.bit_length()
    while q >= Fraction(2) ** (e + 1):
        e += 1
    while q < Fraction(2) ** e:
        e -= 1
    unit = Fraction(2) ** (e - 23)
    return float(sign * round(q / unit) * unit)        # round(): half to even


def _fused_exact(ndc: np.ndarray, half: float) -> np.ndarray:
    """float32(ndc * half + half) with one rounding of the exact value, in rationals."""
    h = Fraction(float(np.float32(half)))
    return np.array([_round_to_float32(Fraction(float(v)) * h + h) for v in ndc], np.float32)


def _unfused(pos, resolution):
    height, width = resolution
    rcp = np.float32(1.0) / pos[:, 3]
    half = np.array([width / 2, height / 2], np.float32)
    return (pos[:, :2] * rcp[:, None]) * half + half


def _vertices(n, seed):
    """Random vertices over the viewport and a guard band around it, log-uniform w, some
    with NDC close to 0 (where the float64 emulation of the fused step rounds too)."""
    rng = np.random.default_rng(seed)
    ndc = rng.uniform(-1.2, 1.2, (n, 2))
    ndc[: n // 8] *= 2.0 ** rng.uniform(-30, -8, (n // 8, 1))
    w = np.exp(rng.uniform(np.log(0.05), np.log(50.0), n))
    z = rng.uniform(-0.9, 0.9, n)
    return np.column_stack([ndc * w[:, None], z * w, w]).astype(np.float32)


@pytest.mark.parametrize("resolution", RESOLUTIONS + [(512, 1024)])
def test_window_float32_rounds_the_viewport_step_once(resolution):
    """Bit for bit the exactly rounded fma(ndc, W/2, W/2), ndc = x_c * float32(1 / w_c)."""
    height, width = resolution
    pos = _vertices(4000, seed=width)
    win = window_float32(pos, resolution)
    rcp = np.float32(1.0) / pos[:, 3]
    for axis, half in ((0, width / 2), (1, height / 2)):
        ndc = pos[:, axis] * rcp
        assert np.array_equal(win[:, axis], _fused_exact(ndc, half)), axis


def test_window_xy_and_shapes_agree():
    """The column form equals the interleaved one, for (V, 4) and gathered (T, 3, 4)."""
    pos, tri = synthetic.random_soup(500, seed=3)
    res = (777, 999)
    x, y = window_xy_float32(pos, res)
    win = window_float32(pos, res)
    assert x.dtype == y.dtype == win.dtype == np.float32
    assert np.array_equal(win, np.stack([x, y], -1))
    assert np.array_equal(window_float32(pos[tri], res), win[tri])
    assert np.array_equal(window_float32(pos.astype(np.float64), res), win)


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_culling_snaps_the_vertices_the_reference_snaps(resolution):
    """glraster.gpu.cull's per-vertex window positions and fixed-point vertices equal
    snap(window_float32(...)), the reference's, for every one of 600k vertices; the unfused
    transform culling used before snaps 0.15-0.5% of them elsewhere."""
    pos = np.concatenate([_vertices(300_000, seed=resolution[1]),
                          synthetic.random_soup(100_000, seed=1)[0]])
    wx, wy, fx, fy = window_fixed(pos, resolution)
    win = window_float32(pos, resolution)
    reference = snap(win)
    assert np.array_equal(np.stack([wx, wy], -1), win)
    assert np.array_equal(np.stack([fx, fy], -1), reference)
    unfused = snap(_unfused(pos, resolution))
    differing = (unfused != reference).any(axis=1).mean()
    assert 1e-3 < differing < 1e-2


def test_snap_rounds_half_to_even_after_a_float32_subtraction():
    half_units = np.arange(-8, 8) + 0.5                 # (x_w - 0.5) * 256 exactly k + 1/2
    window = (half_units / FIXED_ONE + 0.5).astype(np.float32)
    assert np.array_equal(snap(window), np.round(half_units))   # numpy rounds half to even
    # x_w - 0.5 rounds in float32 first (llvmpipe subtracts the pixel offset in float):
    # x_w = 2.5/256 + 2^-30 gives exactly -125.5 + 2^-22 units (nearest: -125), but in
    # float32 the subtraction lands on the tie -125.5, which rounds to even
    x_w = np.array([2.5 / 256 + 2.0**-30], np.float32)
    assert float(x_w[0]) == 2.5 / 256 + 2.0**-30
    assert snap(x_w)[0] == -126
    assert snap(np.array([np.inf, np.nan], np.float32)).dtype == np.float32
