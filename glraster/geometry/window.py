"""The viewport transform from clip space to window coordinates, written once.

GL 4.5 core section 13.8: x_w = (x_c / w_c + 1) W/2, y_w = (y_c / w_c + 1) H/2, with pixel
(i, j) centered at (i + 0.5, j + 0.5). :func:`window_float32` is the float32 form the
driver computes (llvmpipe's, fused); the reference's fixed-point coverage and the GPU-side
culling both use it, so they snap the same vertices.
"""

from __future__ import annotations

import numpy as np


def window_float32(clip: np.ndarray, resolution) -> np.ndarray:
    """Window x, y of clip-space vertices as the driver computes them, in float32.

    clip: (..., 4) float32. Returns (..., 2) float32: x_w = (x_c * (1 / w_c)) W/2 + W/2,
    the last step fused (llvmpipe's viewport transform is an fmuladd, which LLVM fuses on
    x86 with FMA). The rounding matters: snapping to 1/256 px amplifies one float32 ulp
    of x_w (3e-5 px at x = 300) into a different fixed-point vertex about 1.5% of the time,
    and measured coverage on large jittered grids matches only with the fused form.
    """
    height, width = resolution
    c = clip.astype(np.float32)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        rcp = np.float32(1.0) / c[..., 3]
        scale = np.array([width / 2, height / 2], np.float32)
        ndc = c[..., :2] * rcp[..., None]
        # one rounding for scale * ndc + translate (a fused multiply-add)
        return (ndc.astype(np.float64) * scale + scale).astype(np.float32)
