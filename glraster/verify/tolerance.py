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

import numpy as np

from glraster import jit
from glraster.errors import ArgumentError
from glraster.geometry.triangles import TriangleGeometry
from glraster.types import VALUE_OUTPUTS


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
    # glraster/gpu/homogeneous.py), so the position-dependent terms (|grad f| (R + kappa D)
    # and the vertex-value term) shrink by a factor eps32 (glraster.gpu.methods sets it per method).
    compensated: bool = False
    # persp computed from the window-space barycentrics divided by w ("divw"): it carries
    # the noperspective interpolation error too (see value_tolerance).
    persp_from_screen: bool = False
    # Multisampling: the driver divides the b_i / w_i it interpolates at a sample or
    # centroid by the 1 / w of the pixel center, so perspective-correct values off the
    # center are wrong (llvmpipe 22.3; the probe sample_perspective measures it). Where
    # set, persp with interpolation "sample" / "centroid" is waived (counted, not judged).
    center_one_over_w: bool = False

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


def mesa_noperspective_clip_bug(triangles: TriangleGeometry) -> np.ndarray:
    """(T,) bool: triangles whose noperspective values llvmpipe 22.3 gets wrong, from their
    ``x_plane_crossed`` and ``planes_crossed`` (:class:`TriangleGeometry`).

    Mesa's clipper clips against x = -w, x = +w first, then y, then z. It takes the
    window-space blend factor of a new vertex from the first coordinate whose *clip-space*
    values differ along the edge, x before y. After an x plane, the edge that lies on it
    has equal NDC x but different clip x, so a later plane divides 0 by 0 there. Measured:
    every wrong noperspective pixel on random clipped soups belongs to a triangle that
    crosses an x plane and at least one other plane, and only those.
    """
    return triangles.x_plane_crossed & (triangles.planes_crossed >= 2)


def depth_error(triangles: TriangleGeometry, model: ErrorModel = ErrorModel()) -> np.ndarray:
    """(T, 2) float64: bounds on the driver's window-depth error on each triangle, from its
    ``depth_plane`` and ``conditioning`` (:class:`TriangleGeometry`): the
    depth bound of :func:`value_tolerance` with |depth| <= 1: column 0 at pixel centers
    inside the triangle, column 1 outside it (covered because the fixed-point vertices
    differ from the float ones). Inside, the rounding of the vertex values and positions
    reaches the plane as a convex combination, so the D / h term that amplifies it does
    not apply; outside, the plane extrapolates and it does. Used for depth ties by the
    reference: a sliver snapped to 40x its area was measured 3.8e-4 off in depth where
    it extrapolates (1M-triangle terrain at 4096x4096)."""
    cond = triangles.conditioning
    grad_z = np.abs(triangles.depth_plane[:, 0]) + np.abs(triangles.depth_plane[:, 1])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        base = 1 + cond.S / 2 + grad_z * (cond.R + cond.kappa * cond.D)
        bound = model.ulp_factor * EPS32 * np.stack([base, base + cond.D / cond.h], 1) \
            + (grad_z * model.position_error_px)[:, None]
    return np.nan_to_num(bound, nan=np.inf, posinf=np.inf)


@dataclass
class Tolerances:
    """Per-pixel bounds on |GPU - reference| from :func:`value_tolerance`, float64, 0 at
    empty pixels; an output not asked for is None.

    persp, screen : (H, W, 3)    depth : (H, W)
    """

    persp: np.ndarray | None = None
    screen: np.ndarray | None = None
    depth: np.ndarray | None = None


def value_tolerance(triangles: TriangleGeometry | None, tri_id: np.ndarray,
                    outputs=VALUE_OUTPUTS, model: ErrorModel = ErrorModel(),
                    offset=(0.5, 0.5)) -> Tolerances:
    """Per-pixel tolerances of the value outputs of a raster.

    triangles : the T triangles' :class:`TriangleGeometry` (the reference's
        ``ReferenceRaster.triangles``), or None when there are none
    tri_id : (H, W) int, the triangle seen at each pixel (index into ``triangles``), -1
        where empty (the reference's ``tri_id``)
    outputs : which of "persp", "screen", "depth" to bound (the others stay None)
    offset : (ox, oy), where in the pixel the values were evaluated (pixel units; the
        center by default, a sample position when multisampling): the bound is the same
        model evaluated at (x + ox, y + oy)

    The per-pixel bounds are evaluated by a compiled loop (:func:`_tolerances`).
    """
    names = tuple(outputs)
    unknown = [o for o in names if o not in VALUE_OUTPUTS]
    if unknown:
        raise ArgumentError("outputs", f"outputs must be among {VALUE_OUTPUTS}, got {unknown}")
    height, width = tri_id.shape
    n = height * width
    ts = triangles
    tri_flat = tri_id.reshape(-1).astype(np.int64)
    pix = np.flatnonzero(tri_flat >= 0)
    screen = np.zeros((n, 3) if "screen" in names else (0, 3))
    persp = np.zeros((n, 3) if "persp" in names else (0, 3))
    depth = np.zeros(n if "depth" in names else 0)
    if ts is not None and len(pix):
        cond = ts.conditioning
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # inf (an unmeasurable clipped polygon) times 0 must stay inf, not NaN
            reach = np.nan_to_num(cond.R + cond.kappa * cond.D, nan=np.inf)
            # The gradient's numerator (e.g. df01 dy20 - dy01 df20) rounds each vertex
            # value f_v: an error of eps32 |f_v| / h per pixel of distance, over up to D px.
            span = np.nan_to_num(cond.D / cond.h, nan=np.inf)
        _tolerances(pix, tri_flat, width,
                    ts.adj, ts.det, np.ascontiguousarray(ts.clip, dtype=np.float64), reach,
                    span, cond.S, cond.N, cond.wmin, model.ulp_factor * EPS32,
                    model.position_error_px,
                    # compensated evaluation: the position terms carry eps32^2
                    EPS32 if model.compensated else 1.0, model.persp_from_screen,
                    screen, persp, depth, float(offset[0]), float(offset[1]))
    return Tolerances(
        persp=persp.reshape(height, width, 3) if "persp" in names else None,
        screen=screen.reshape(height, width, 3) if "screen" in names else None,
        depth=depth.reshape(height, width) if "depth" in names else None,
    )


@jit.njit(nogil=True, error_model="numpy")
def _bound(unit, value, grad, vertex_value, shrink, reach, span, delta):
    """unit (|f| + shrink (|grad f|_1 reach + F span)) + |grad f|_1 delta, NaN -> inf:
    the module docstring's bound with unit = C eps32."""
    b = unit * (value + shrink * (grad * reach + vertex_value * span)) + grad * delta
    return np.inf if math.isnan(b) else b


@jit.njit(nogil=True, error_model="numpy")
def _tolerances(pix, tri_id, width, adj, det, clip, reach, span, S, N, wmin, unit, delta,
                shrink, persp_from_screen, screen_tol, persp_tol, depth_tol, ox=0.5, oy=0.5):
    """Fill the bounds of :func:`value_tolerance` at the covered pixels ``pix`` (K,) of
    ``tri_id`` (H*W,): screen_tol and persp_tol (H*W, 3), depth_tol (H*W,), each skipped
    when empty. adj (T, 3, 3), det (T,), clip (T, 3, 4) from the TriangleGeometry; reach =
    R + kappa D, span = D / h, S, N, wmin (T,) from :func:`triangle_conditioning`."""
    s = np.empty(3)
    grad = np.empty(3)
    screen = np.empty(3)
    dq = np.empty(3)
    for i in range(pix.shape[0]):
        p = pix[i]
        t = tri_id[p]
        cx = p % width + ox
        cy = p // width + oy
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
