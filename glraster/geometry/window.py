"""The viewport transform from clip space to window coordinates, written once.

GL 4.5 core section 13.8: x_w = (x_c / w_c + 1) W/2, y_w = (y_c / w_c + 1) H/2, with pixel
(i, j) centered at (i + 0.5, j + 0.5). :func:`window_float32` is the float32 form the
driver computes (llvmpipe's, fused); the reference's fixed-point coverage and the GPU-side
culling (glraster.gpu.cull) both use it, and both snap with
glraster.geometry.fill_rule.snap, so they agree on every fixed-point vertex.
"""

from __future__ import annotations

import numpy as np


def window_float32(clip: np.ndarray, resolution) -> np.ndarray:
    """Window x, y of clip-space vertices as the driver computes them, in float32.

    clip: (..., 4) float32. Returns (..., 2) float32: x_w = (x_c * (1 / w_c)) W/2 + W/2,
    the last step fused (llvmpipe's viewport transform is an fmuladd, which LLVM fuses on
    x86 with FMA). The rounding matters: snapping to 1/256 px amplifies one float32 ulp
    of x_w (3e-5 px at x = 300) into a different fixed-point vertex about 1.5% of the time,
    and measured coverage on large jittered grids matches only with the fused form. The
    unfused ``(x_c * rcp) * sx + sx`` rounds twice and snaps 0.15-0.3% of the coordinates
    of random vertices differently at widths and heights that are not powers of two (at
    powers of two the product is exact and both forms agree).

    Elementwise per vertex, so it serves (V, 4) vertex arrays (culling, 1M-triangle meshes)
    as well as (T, 3, 4) gathered triangles (the reference). The fused step is emulated in
    float64: the product of two float32 values is exact there, and the sum is rounded once
    to float64 before float32; the two roundings can differ from one fused rounding only
    when the float64 sum lands exactly on a float32 tie, which needs |x_c / w_c| near 2^-25
    (an exhaustive search over float32 NDC at eight viewport sizes found 2 such values, both
    within 1e-5 px of the viewport center, far from a snapping boundary).
    """
    x_w, y_w = window_xy_float32(clip, resolution)
    return np.stack([x_w, y_w], axis=-1)


def window_xy_float32(clip: np.ndarray, resolution):
    """:func:`window_float32` as two separate contiguous arrays (x_w, y_w), each of shape
    ``clip.shape[:-1]``: the same values, computed column by column, which is several times
    cheaper than on interleaved (..., 2) arrays (glraster.gpu.cull on 1M-triangle meshes)."""
    height, width = resolution
    c = np.asarray(clip, dtype=np.float32)              # no copy for float32 input
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        rcp = np.float32(1.0) / c[..., 3]
        x_w = _fused_viewport(c[..., 0] * rcp, width / 2)
        y_w = _fused_viewport(c[..., 1] * rcp, height / 2)
    return x_w, y_w


def _fused_viewport(ndc: np.ndarray, half_size: float) -> np.ndarray:
    """float32(ndc * half_size + half_size) rounded once: ndc float32 (its product with the
    float32 half size is exact in float64), half_size = W/2 or H/2 (exact in float32)."""
    assert ndc.dtype == np.float32
    h = np.float64(np.float32(half_size))
    fused = np.multiply(ndc, h, dtype=np.float64)
    fused += h
    return fused.astype(np.float32)
