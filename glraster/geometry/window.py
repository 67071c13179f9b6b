"""The viewport transform from clip space to window coordinates, written once.

GL 4.5 core section 13.8: x_w = (x_c / w_c + 1) W/2, y_w = (y_c / w_c + 1) H/2, with pixel
(i, j) centered at (i + 0.5, j + 0.5). :func:`window_float32` is the float32 form the
driver computes (llvmpipe's, fused); the reference's fixed-point coverage and the GPU-side
culling (glraster.gpu.cull) both use it, and both snap with
glraster.geometry.fill_rule.snap, so they agree on every fixed-point vertex.
:func:`clip_to_window` and :func:`window_to_clip` are the float64 conversions both ways
(cameras, scene builders, stress sweeps).
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError


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


# -- float64 conversions between clip and window coordinates ------------------------------

def clip_to_window(pos, resolution) -> np.ndarray:
    """Window coordinates of clip-space positions (DESIGN.md conventions).

    Args:
        pos: (V, 4) clip-space positions (any float dtype; computed in float64).
        resolution: (H, W).

    Returns:
        (V, 3) float64 ``(x_w, y_w, z_w)`` with ``x_w = (x/w + 1) W/2``,
        ``y_w = (y/w + 1) H/2``, ``z_w = (z/w) / 2 + 1/2``.
    """
    p = validate.float_array("pos", pos, (-1, 4))
    if len(resolution) != 2:
        raise ArgumentError("resolution", f"resolution must be (H, W), got {resolution!r}")
    H, W = validate.positive_int("resolution[0]", resolution[0]), validate.positive_int("resolution[1]", resolution[1])
    ndc = p[:, :3] / p[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) * W / 2, (ndc[:, 1] + 1) * H / 2, ndc[:, 2] * 0.5 + 0.5],
                    axis=1)


def window_to_clip(xy_window: np.ndarray, resolution, z_ndc=0.0, w=1.0) -> np.ndarray:
    """Clip-space positions whose window coordinates are xy_window.

    xy_window: (V, 2) window coordinates in pixels (GL convention: pixel (i, j) has its
    center at (i + 0.5, j + 0.5), origin bottom-left). resolution: (height, width).
    z_ndc, w: scalars or (V,) arrays; x, y, z are multiplied by w so the divide by w lands
    on the requested window point. Returns (V, 4) float64.
    """
    xy = np.asarray(xy_window, dtype=np.float64)
    h, w_px = resolution
    n = len(xy)
    z_ndc = np.broadcast_to(np.asarray(z_ndc, dtype=np.float64), (n,))
    w = np.broadcast_to(np.asarray(w, dtype=np.float64), (n,))
    x_ndc = 2.0 * xy[:, 0] / w_px - 1.0
    y_ndc = 2.0 * xy[:, 1] / h - 1.0
    return np.stack([x_ndc * w, y_ndc * w, z_ndc * w, w], axis=1)
