"""Per-pixel value tolerances from an error model of float32 plane-equation interpolation.

A driver interpolates an attribute f that is linear in window space (a window-space
barycentric, the perspective numerator b_i / w_i, 1 / w, or depth) from plane equations set
up in float32 from the (float32) window positions of the vertices, anchored at the
framebuffer origin, then evaluated at the pixel center: f(p) = a0 + dfdx x + dfdy y. In the
spirit of the Khronos CTS verifiers we bound the error of that computation rather than pick
one number:

    |df| <= C eps32 ( |f(p)|  +  |grad f|_1 (R + kappa D) )  +  |grad f|_1 delta

- eps32 |f(p)|: rounding of the evaluation and of the stored float32;
- eps32 |grad f|_1 R: R = max_i (|v_i|_1 + |v_i - c|_1), how far the vertices are from
  the origin and from the viewport center c, in pixels: the anchor a0 = f(v_0) - grad f . v_0
  at the origin grows with the first, the rounding of x_w = x_ndc W/2 + W/2 with both;
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

import math
from dataclasses import dataclass

import numba
import numpy as np


EPS32 = float(np.finfo(np.float32).eps)  # 2^-23


@dataclass(frozen=True)
class ErrorModel:
    """Parameters of the tolerance bound (see the module docstring).

    ulp_factor : C, the number of float32 roundings allowed per term
    position_error_px : delta, sample-position uncertainty in pixels
    waived_outputs : outputs not judged on the triangles :func:`mesa_noperspective_clip_bug`
        selects, where Mesa's draw-module clipper (llvmpipe 22.3) breaks GL's rule for
        noperspective values (docs/llvmpipe.md): the outputs a method computes from the
        driver's noperspective varyings. Waived pixels are counted in the report, never
        hidden.
    """

    ulp_factor: float = 4.0
    position_error_px: float = 0.0
    waived_outputs: tuple[str, ...] = ("screen",)
    # compensated: the barycentrics (not depth, which stays the driver's) are evaluated in
    # about twice the working precision and rounded once ("homogeneous", "homogeneous64":
    # glraster/homogeneous.py), so the position-dependent terms (|grad f| (R + kappa D)
    # and the vertex-value term) shrink by a factor eps32. See for_method().
    compensated: bool = False
    # persp computed from the window-space barycentrics divided by w ("divw"): it carries
    # the noperspective interpolation error too (see value_tolerance).
    persp_from_screen: bool = False

    @classmethod
    def for_context(cls, ctx) -> "ErrorModel":
        """The model for a context: exact sample positions on llvmpipe, else the driver's
        subpixel precision (at least the 4 bits GL requires)."""
        if ctx is None or ctx.is_llvmpipe:
            return cls()
        return cls(
            position_error_px=2.0 ** -max(4, min(ctx.subpixel_bits, 16)),
            waived_outputs=(),
        )

    @classmethod
    def for_method(cls, method: str, ctx=None) -> "ErrorModel":
        """The model for one of :data:`glraster.gpu.rasterize.METHODS` on a context.

        "hw", "divw" and "solve4" interpolate or solve in plain float32 from the same
        float32 window-space data as the driver: the driver model (:meth:`for_context`)
        bounds them (measured: worst error / tolerance <= 0.62 on the benchmark scenes,
        docs/performance.md). divw's persp divides the noperspective barycentrics by w,
        so its bound adds the screen bound carried through that division
        (``persp_from_screen``). Waived on a driver with the clipper defect: hw's screen
        (noperspective varyings), and divw's screen and persp. solve4 and the "homogeneous" methods compute
        barycentrics from the unclipped triangle, so nothing is waived for them;
        "homogeneous" and "homogeneous64" evaluate compensated as well.
        """
        from dataclasses import replace

        from glraster.gpu.rasterize import METHODS

        if method not in METHODS:
            raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
        base = cls.for_context(ctx)
        if method in ("homogeneous", "homogeneous64"):
            return replace(base, compensated=True, waived_outputs=())
        if method == "solve4":
            return replace(base, waived_outputs=())
        if method == "divw":
            waived = ("screen", "persp") if base.waived_outputs else ()
            return replace(base, waived_outputs=waived, persp_from_screen=True)
        return base


def mesa_noperspective_clip_bug(setup) -> np.ndarray:
    """(T,) bool: triangles whose noperspective values llvmpipe 22.3 gets wrong.

    Mesa's clipper clips against x = -w, x = +w first, then y, then z. It takes the
    window-space blend factor of a new vertex from the first coordinate whose *clip-space*
    values differ along the edge, x before y. After an x plane, the edge that lies on it
    has equal NDC x but different clip x, so a later plane divides 0 by 0 there. Measured:
    every wrong noperspective pixel on random clipped soups belongs to a triangle that
    crosses an x plane and at least one other plane, and only those.
    """
    return setup.x_plane_crossed & (setup.planes_crossed >= 2)


def depth_error(setup, model: ErrorModel = ErrorModel()) -> np.ndarray:
    """(T, 2) float64: bounds on the driver's window-depth error on each triangle, the
    depth bound of :func:`value_tolerance` with |depth| <= 1: column 0 at pixel centers
    inside the triangle, column 1 outside it (covered because the fixed-point vertices
    differ from the float ones). Inside, the rounding of the vertex values and positions
    reaches the plane as a convex combination, so the D / h term that amplifies it does
    not apply; outside, the plane extrapolates and it does. Used for depth ties by the
    reference: a sliver snapped to 40x its area was measured 3.8e-4 off in depth where
    it extrapolates (1M-triangle terrain at 4096x4096)."""
    cond = setup.conditioning
    grad_z = np.abs(setup.depth_plane[:, 0]) + np.abs(setup.depth_plane[:, 1])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        base = 1 + cond.S / 2 + grad_z * (cond.R + cond.kappa * cond.D)
        bound = model.ulp_factor * EPS32 * np.stack([base, base + cond.D / cond.h], 1) \
            + (grad_z * model.position_error_px)[:, None]
    return np.nan_to_num(bound, nan=np.inf, posinf=np.inf)


def value_tolerance(ref, model: ErrorModel = ErrorModel()) -> dict:
    """Per-pixel tolerances for every value output of a reference raster.

    ref: ReferenceRaster computed with "tri_id" among its outputs. Returns a dict mapping
    "persp" and "screen" to (H, W, 3) float64 and "depth" to (H, W) float64 bounds on
    |GPU - reference|, for the outputs the reference holds; 0 at empty pixels. The
    per-pixel bounds are evaluated by a compiled loop (:func:`_tolerances`).
    """
    height, width = ref.resolution
    n = height * width
    ts = ref.setup
    screen = np.zeros((n, 3) if ref.screen is not None else (0, 3))
    persp = np.zeros((n, 3) if ref.persp is not None else (0, 3))
    depth = np.zeros(n if ref.depth is not None else 0)
    if ts is not None and ref.mask.any():
        cond = ts.conditioning
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # inf (an unmeasurable clipped polygon) times 0 must stay inf, not NaN
            reach = np.nan_to_num(cond.R + cond.kappa * cond.D, nan=np.inf)
            # The gradient's numerator (e.g. df01 dy20 - dy01 df20) rounds each vertex
            # value f_v: an error of eps32 |f_v| / h per pixel of distance, over up to D px.
            span = np.nan_to_num(cond.D / cond.h, nan=np.inf)
        _tolerances(np.flatnonzero(ref.mask), ref.tri_id.reshape(-1).astype(np.int64), width,
                    ts.adj, ts.det, np.ascontiguousarray(ts.clip, dtype=np.float64), reach,
                    span, cond.S, cond.N, cond.wmin, model.ulp_factor * EPS32,
                    model.position_error_px,
                    # compensated evaluation: the position terms carry eps32^2
                    EPS32 if model.compensated else 1.0, model.persp_from_screen,
                    screen, persp, depth)
    out = {}
    if ref.screen is not None:
        out["screen"] = screen.reshape(height, width, 3)
    if ref.persp is not None:
        out["persp"] = persp.reshape(height, width, 3)
    if ref.depth is not None:
        out["depth"] = depth.reshape(height, width)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bound(unit, value, grad, vertex_value, shrink, reach, span, delta):
    """unit (|f| + shrink (|grad f|_1 reach + F span)) + |grad f|_1 delta, NaN -> inf:
    the module docstring's bound with unit = C eps32."""
    b = unit * (value + shrink * (grad * reach + vertex_value * span)) + grad * delta
    return np.inf if math.isnan(b) else b


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _tolerances(pix, tri_id, width, adj, det, clip, reach, span, S, N, wmin, unit, delta,
                shrink, persp_from_screen, screen_tol, persp_tol, depth_tol):
    """Fill the bounds of :func:`value_tolerance` at the covered pixels ``pix`` (K,) of
    ``tri_id`` (H*W,): screen_tol and persp_tol (H*W, 3), depth_tol (H*W,), each skipped
    when empty. adj (T, 3, 3), det (T,), clip (T, 3, 4) from the reference setup; reach =
    R + kappa D, span = D / h, S, N, wmin (T,) from :func:`triangle_conditioning`."""
    s = np.empty(3)
    grad = np.empty(3)
    screen = np.empty(3)
    dq = np.empty(3)
    for i in range(pix.shape[0]):
        p = pix[i]
        t = tri_id[p]
        cx = p % width + 0.5
        cy = p // width + 0.5
        for k in range(3):                               # s = M^-1 (p, 1), |grad s_k|_1
            s[k] = (adj[t, k, 0] * cx + adj[t, k, 1] * cy + adj[t, k, 2]) / det[t]
            grad[k] = (abs(adj[t, k, 0]) + abs(adj[t, k, 1])) / abs(det[t])
        r, sp = reach[t], span[t]
        for k in range(3):
            # a clipped vertex's window-space blend factor carries eps32 N (see N)
            w = clip[t, k, 3]
            screen[k] = _bound(unit, abs(s[k] * w) + N[t], grad[k] * abs(w), 1.0, shrink, r,
                               sp, delta)
        if screen_tol.shape[0]:
            screen_tol[p, :] = screen
        if persp_tol.shape[0]:
            total = s[0] + s[1] + s[2]                   # Q = 1 / w_p
            for k in range(3):
                # a clipped vertex's 1 / w carries a relative error of about eps32 S
                dq[k] = _bound(unit, abs(s[k]) * (1 + S[t]), grad[k], 1.0 / wmin[t], shrink,
                               r, sp, delta)
            dq_sum = dq[0] + dq[1] + dq[2]
            carried_sum = 0.0
            for k in range(3):
                carried_sum += screen[k] / abs(clip[t, k, 3])
            for k in range(3):
                persp = abs(s[k] / total)
                tol = (dq[k] + persp * dq_sum) / total + unit * persp
                if persp_from_screen:
                    # divw: persp_i = (screen_i / w_i) / sum_j (screen_j / w_j), that sum
                    # is Q: screen errors d_j reach persp as (d_i / w_i + persp_i
                    # sum_j d_j / w_j) / Q
                    carried = (screen[k] / abs(clip[t, k, 3]) + persp * carried_sum) \
                        / abs(total)
                    tol += np.inf if math.isnan(carried) else carried
                persp_tol[p, k] = tol
        if depth_tol.shape[0]:
            zw = (s[0] * clip[t, 0, 2] + s[1] * clip[t, 1, 2] + s[2] * clip[t, 2, 2]) * 0.5 + 0.5
            gx, gy = 0.0, 0.0
            for k in range(3):
                gx += adj[t, k, 0] * (clip[t, k, 2] / det[t])
                gy += adj[t, k, 1] * (clip[t, k, 2] / det[t])
            # a clipped vertex's depth carries eps32 S / 2 from its float32 blend (see S);
            # depth comes from the driver, never compensated
            depth_tol[p] = _bound(unit, abs(zw) + S[t] / 2, 0.5 * (abs(gx) + abs(gy)), 1.0,
                                  1.0, r, sp, delta)
