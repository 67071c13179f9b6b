"""Per-pixel value tolerances from an error model of float32 plane-equation interpolation.

A driver interpolates an attribute f that is linear in window space (a window-space
barycentric, the perspective numerator b_i / w_i, 1 / w, or depth) from plane equations set
up in float32 from the (float32) window positions of the vertices, anchored at the
framebuffer origin, then evaluated at the pixel center: f(p) = a0 + dfdx x + dfdy y. In the
spirit of the Khronos CTS verifiers we bound the error of that computation rather than pick
one number:

    |df| <= C eps32 ( |f(p)|  +  |grad f|_1 (R + kappa D) )  +  |grad f|_1 delta

- eps32 |f(p)|: rounding of the evaluation and of the stored float32;
- eps32 |grad f|_1 R: R = max_i |v_i|_1, how far the vertices (and so the pixel and the
  anchor a0 at the origin) are from the origin, in pixels: rounding of the window positions
  and of a0 = f(v_0) - grad f . v_0 grows with it;
- eps32 |grad f|_1 kappa D: the gradient's relative error is about eps32 kappa, with
  kappa = (|dx01 dy20| + |dx20 dy01|) / |dx01 dy20 - dx20 dy01| the cancellation in the
  triangle's area, carried over D = the triangle's L1 diameter from where it is anchored;
- |grad f|_1 delta: sample-position uncertainty, delta = 0 for drivers that interpolate from
  unsnapped positions at the exact center (llvmpipe), 2^-subpixel_bits otherwise.

Perspective-correct barycentrics are q_i / Q with q_i = b_i / w_i and Q = sum_j q_j = 1 / w,
both interpolated this way, so their bound is (dq_i + persp_i dQ) / Q plus one rounding.
The constant C absorbs the handful of roundings in each step; it was calibrated on llvmpipe
(docs/tolerance.md) and holds with margin over the measured worst case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS32 = float(np.finfo(np.float32).eps)  # 2^-23


@dataclass(frozen=True)
class ErrorModel:
    """Parameters of the tolerance bound (see the module docstring).

    ulp_factor : C, the number of float32 roundings allowed per term
    position_error_px : delta, sample-position uncertainty in pixels
    """

    ulp_factor: float = 4.0
    position_error_px: float = 0.0

    @classmethod
    def for_context(cls, ctx) -> "ErrorModel":
        """The model for a context: exact sample positions on llvmpipe, else the driver's
        subpixel precision (at least the 4 bits GL requires)."""
        if ctx is None or ctx.is_llvmpipe:
            return cls()
        return cls(position_error_px=2.0 ** -max(4, min(ctx.subpixel_bits, 16)))


def triangle_conditioning(setup, resolution):
    """Per-triangle (R, kappa, D), each (T,) float64, from the window-space vertices.

    Triangles with a vertex behind the eye or outside the near/far planes use the
    vertices of their near/far-clipped polygon (what the driver's clipper produces).
    """
    from .reference import _clip_near_far

    height, width = resolution
    clip = setup.clip
    T = len(clip)
    R = np.zeros(T)
    kappa = np.ones(T)
    D = np.zeros(T)
    scale = np.array([width / 2, height / 2])
    w = clip[..., 3]
    simple = (w > 0).all(1) & (np.abs(clip[..., 2]) <= w).all(1)

    def measure(v):  # v: (N, k, 2) window positions of N polygons with k vertices
        R_ = np.abs(v).sum(-1).max(-1)
        diff = v[:, :, None, :] - v[:, None, :, :]
        D_ = np.abs(diff).sum(-1).max((-1, -2))
        d01 = v[:, :1] - v[:, 1:]                     # fan from vertex 0
        a = d01[:, :-1]
        b = d01[:, 1:]
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        mag = np.abs(a[..., 0] * b[..., 1]) + np.abs(a[..., 1] * b[..., 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            k = np.where(np.abs(cross) > 0, mag / np.abs(cross), np.inf)
        return R_, np.maximum(np.nan_to_num(k.max(-1), nan=np.inf), 1.0), D_

    if simple.any():
        win = (clip[simple][..., :2] / w[simple][..., None] + 1) * scale
        R[simple], kappa[simple], D[simple] = measure(win)
    for t in np.flatnonzero(~simple):
        poly = _clip_near_far(clip[t])
        if len(poly) < 3 or (poly[:, 3] <= 0).any():
            R[t], kappa[t], D[t] = np.inf, np.inf, np.inf
            continue
        win = (poly[:, :2] / poly[:, 3:4] + 1) * scale
        r, k, d = measure(win[None])
        R[t], kappa[t], D[t] = r[0], k[0], d[0]
    return R, kappa, D


def value_tolerance(ref, model: ErrorModel = ErrorModel()) -> dict:
    """Per-pixel tolerances for every value output of a reference raster.

    ref: ReferenceRaster computed with "tri_id" among its outputs. Returns a dict mapping
    "persp" and "screen" to (H, W, 3) float64 and "depth" to (H, W) float64 bounds on
    |GPU - reference|, for the outputs the reference holds; 0 at empty pixels.
    """
    from .reference import _edge_values

    height, width = ref.resolution
    ts = ref.setup
    out = {}
    pix = np.flatnonzero(ref.mask)
    if ts is None or not len(pix):
        for name in ("persp", "screen"):
            if getattr(ref, name) is not None:
                out[name] = np.zeros((height, width, 3))
        if ref.depth is not None:
            out["depth"] = np.zeros((height, width))
        return out

    R, kappa, D = triangle_conditioning(ts, ref.resolution)
    t = ref.tri_id.reshape(-1)[pix]
    s, adj = _edge_values(ts, t, pix % width, pix // width)
    det = ts.det[t][:, None]
    grad_s = (np.abs(adj[..., 0]) + np.abs(adj[..., 1])) / np.abs(det)   # |grad s_i|_1
    reach = (R + kappa * D)[t][:, None]
    C, delta = model.ulp_factor, model.position_error_px

    def bound(value, grad):
        with np.errstate(invalid="ignore"):
            b = C * EPS32 * (np.abs(value) + grad * reach) + grad * delta
        return np.nan_to_num(b, nan=np.inf)

    w = ts.clip[t, :, 3]
    if ref.screen is not None:
        tol = np.zeros((height * width, 3))
        tol[pix] = bound(s * w, grad_s * np.abs(w))
        out["screen"] = tol.reshape(height, width, 3)
    if ref.persp is not None:
        Q = s.sum(1, keepdims=True)
        persp = s / Q
        dq = bound(s, grad_s)
        tol = np.zeros((height * width, 3))
        tol[pix] = (dq + np.abs(persp) * dq.sum(1, keepdims=True)) / Q + C * EPS32 * np.abs(persp)
        out["persp"] = tol.reshape(height, width, 3)
    if ref.depth is not None:
        z = ts.clip[t, :, 2]
        zw = (s * z).sum(1) * 0.5 + 0.5
        grad_z = 0.5 * np.abs((adj[..., :2] * (z / det)[..., None]).sum(1)).sum(1)
        tol = np.zeros(height * width)
        tol[pix] = bound(zw[:, None], grad_z[:, None])[:, 0]
        out["depth"] = tol.reshape(height, width)
    return out
