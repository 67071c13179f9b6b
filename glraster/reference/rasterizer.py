"""The analytic reference rasterizer, in float64: per-triangle setup in NumPy, the loops over
pixels compiled (:mod:`glraster.reference.kernels`).

Formulation (2D homogeneous rasterization, Olano & Greer 1997). With homogeneous window
coordinates X_i = (x_i + w_i) W/2, Y_i = (y_i + w_i) H/2 of the three clip-space vertices, the
3x3 matrix M = [[X_0 X_1 X_2], [Y_0 Y_1 Y_2], [w_0 w_1 w_2]] maps the clip-space barycentrics
of a point to its homogeneous window position. For a pixel center p = (p_x, p_y):

    s = M^-1 (p_x, p_y, 1)            s_i = lambda_i / w_p,   sum(s) = 1 / w_p
    persp_i  = s_i / sum(s)            perspective-correct (GL 4.5 eq. 14.9; Heckbert & Moreton 1991)
    screen_i = s_i w_i                 window-space affine barycentrics (eq. 14.10)
    z_ndc    = sum(s_i z_i),  depth = z_ndc / 2 + 1/2

A point is on the triangle and in front of the eye when every s_i >= 0 (then w_p > 0), and
inside the near/far planes when -1 <= z_ndc <= 1: this handles vertices with w <= 0 and
near/far crossings without splitting triangles, and the values are those of the unclipped
triangle, as GL requires. M^-1 = adj(M) / det(M); the rows of adj(M) are the three edge
functions e_i(p), linear in window space.

Coverage of triangles whose vertices lie inside the viewport follows a driver's fixed-point
fill rule exactly (:class:`~glraster.geometry.fill_rule.FillRule`: subpixel bits, tie rule,
snapping; by default Mesa llvmpipe's, :func:`llvmpipe_edges`); other triangles (clipped by the near/far planes or
reaching outside the viewport, where the driver's clipper makes new float vertices) and
every triangle when ``fill_rule=None`` mark the pixel centers within ``edge_band_px`` of
their edges in ``edge_band``, where either answer is accepted.

Pixels: triangles with a fixed-point edge setup are walked row by row as exact integer
spans; the others test every candidate of their bounding box (clipped to the viewport) in
float64. Every fragment is depth-tested (GL's LESS in draw order); the depth of the best
other fragment is kept too, and where it is within DEPTH_TIE of the winner the pixel is a
depth tie, where either triangle is accepted.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numba
import numpy as np

from glraster.errors import ArgumentError
from glraster.reference import kernels
from glraster import validate
from glraster.types import OUTPUTS
from glraster.geometry.clipping import near_far_extents
from glraster.geometry.conditioning import triangle_conditioning
from glraster.geometry.fill_rule import (  # noqa: F401 (part of this API)
    FIXED_ONE, LLVMPIPE, SUBPIXEL_BITS, FillRule, fixed_edges, llvmpipe_edges,
)
from glraster.geometry.triangles import TriangleGeometry
from glraster.geometry.triangles import edge_functions, homogeneous_vertices
from glraster.geometry.samples import fixed_offsets, standard_positions
from glraster.geometry.window import window_float32
from glraster.types import Raster, first_covered_sample, per_pixel
from glraster.verify.tolerance import depth_error

DEFAULT_EDGE_BAND_PX = 4.0 / FIXED_ONE
# one parallel kernel at a time: numba's workqueue threading layer (used when OpenMP and TBB
# are missing) must not be entered from two threads at once
_PARALLEL_KERNEL = threading.Lock()
# Two fragments at a pixel are a depth tie, where the GPU's float32 plane equations may order
# them either way, when their depths differ by at most this plus both fragments' depth error
# bounds (tolerance.depth_error: large only where an ill-conditioned sliver's plane
# extrapolates). ~2^-17, above the depth error of well-shaped triangles (docs/tolerance.md).
DEPTH_TIE = 2.0**-17


@dataclass
class ReferenceRaster(Raster):
    """A :class:`Raster` from the reference, in float64, plus where it cannot judge.

    edge_band : (H, W) bool   pixel centers within ``edge_band_px`` of an edge of a triangle
                              whose coverage is not modeled exactly: either answer accepted
    depth_tie : (H, W) bool   two triangles within DEPTH_TIE in depth: either may win
    triangles : TriangleGeometry or None   per-triangle geometry of the T input triangles
                              (indexed by ``tri_id``), the input of the error model
                              (:func:`glraster.verify.tolerance.value_tolerance`); None
                              when there are no triangles
    """

    edge_band: np.ndarray | None = None
    depth_tie: np.ndarray | None = None
    triangles: TriangleGeometry | None = field(default=None, repr=False)

    @property
    def ambiguous(self) -> np.ndarray:
        """Pixels whose coverage or winning triangle may differ between correct drivers."""
        return self.edge_band | self.depth_tie


@dataclass
class TriangleSetup(TriangleGeometry):
    """The reference's per-triangle setup: the :class:`TriangleGeometry` (clip, adj, det,
    depth_plane, planes_crossed, x_plane_crossed, conditioning), plus what only the
    rasterizer's own loops use. T triangles.

    exact  : (T,) bool  coverage modeled bit for bit (the fill rule's, no clipping)
    fixed  : (T, 3, 3) int64   fixed-point edges (dcdx, dcdy, c) where ``fixed_ok``
    fixed_ok : (T,) bool  ``fixed`` holds a valid edge setup, used for coverage
    bbox   : (T, 4) int64 x0, x1, y0, y1 inclusive pixel range (x1 < x0: no pixels)
    culled : (T,) bool    produces no fragment (zero area)
    rule   : the FillRule of ``fixed`` (None: no fixed-point model)
    """

    exact: np.ndarray
    fixed: np.ndarray
    fixed_ok: np.ndarray
    bbox: np.ndarray
    culled: np.ndarray
    rule: FillRule | None = None

    def geometry(self) -> TriangleGeometry:
        """The public part, sharing its arrays (no copy)."""
        return TriangleGeometry(
            clip=self.clip, adj=self.adj, det=self.det, depth_plane=self.depth_plane,
            planes_crossed=self.planes_crossed, x_plane_crossed=self.x_plane_crossed,
            conditioning=self.conditioning,
        )


def fill_rule_of(fill_rule) -> FillRule | None:
    """The :class:`FillRule` named by a ``fill_rule`` argument: "llvmpipe" is
    :data:`LLVMPIPE`, a FillRule itself, None none (edge band everywhere)."""
    if fill_rule is None or isinstance(fill_rule, FillRule):
        return fill_rule
    if isinstance(fill_rule, str) and fill_rule == "llvmpipe":
        return LLVMPIPE
    raise ArgumentError("fill_rule", f"fill_rule must be 'llvmpipe' or None (or a "
                                     f"glraster.geometry.fill_rule.FillRule), got {fill_rule!r}")


def setup(pos: np.ndarray, tri: np.ndarray, resolution, fill_rule) -> TriangleSetup:
    """Per-triangle setup of the reference. pos (V, 4) float32, tri (T, 3) int32;
    fill_rule: "llvmpipe", a FillRule or None (see :func:`rasterize`)."""
    rule = fill_rule_of(fill_rule)
    height, width = resolution
    clip32 = pos[tri]                                   # (T, 3, 4) float32
    clip = clip32.astype(np.float64)
    w = clip[..., 3]
    adj, det = edge_functions(homogeneous_vertices(clip, resolution))

    z = clip[..., 2]
    in_front = (w > 0).all(axis=1)
    in_depth = (np.abs(z) <= w).all(axis=1)
    win = window_float32(clip32, resolution)            # (T, 3, 2) float32
    with np.errstate(invalid="ignore"):
        inside = (
            in_front & in_depth
            & (win[..., 0] >= 0).all(1) & (win[..., 0] <= width).all(1)
            & (win[..., 1] >= 0).all(1) & (win[..., 1] <= height).all(1)
        )
        # The fixed-point model stays meaningful (and inside int64) for unclipped
        # triangles within a wide guard band; past it only the float test is used.
        limit = rule.window_limit if rule is not None else 0.0
        modeled = in_front & in_depth & (np.abs(win) < limit).all(axis=(1, 2))
    fixed = np.zeros((len(tri), 3, 3), np.int64)
    fixed_ok = np.zeros(len(tri), bool)
    if rule is not None and modeled.any():
        fixed[modeled], fixed_ok[modeled] = fixed_edges(win[modeled], rule)
    exact = inside if rule is not None else np.zeros(len(tri), bool)

    x, y = clip[..., 0], clip[..., 1]
    outside = np.stack([x > w, x < -w, y > w, y < -w, z > w, z < -w], -1).any(1)
    # depth = z_ndc / 2 + 1/2 with z_ndc = sum_i z_i e_i(p) / det: a plane in window space
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_plane = 0.5 * np.einsum("ti,tij->tj", z, adj) / det[:, None]
    depth_plane[:, 2] += 0.5
    # Nothing to rasterize: zero window area (det = 0), or the driver culls the triangle
    # because it snaps to zero area (llvmpipe does).
    culled = (det == 0) | ~np.isfinite(depth_plane).all(1) | (exact & ~fixed_ok)
    bbox = _bounding_boxes(clip, resolution, w, z)
    bbox[culled] = (0, -1, 0, -1)
    planes_crossed = outside.sum(1)
    return TriangleSetup(
        clip=clip, adj=adj, det=det, depth_plane=depth_plane, planes_crossed=planes_crossed,
        x_plane_crossed=outside[:, :2].any(1),
        conditioning=triangle_conditioning(clip, planes_crossed == 0, resolution),
        exact=exact, fixed=fixed, fixed_ok=fixed_ok & modeled, bbox=bbox, culled=culled,
        rule=rule,
    )


def _bounding_boxes(clip, resolution, w, z) -> np.ndarray:
    """(T, 4) inclusive pixel ranges x0, x1, y0, y1 that can hold a fragment, widened by one
    pixel for the edge band and clipped to the viewport. Triangles crossing the near or far
    plane are clipped in clip space first; if a clipped vertex reaches w ~ 0 the whole
    viewport is used."""
    height, width = resolution
    T = len(clip)
    lo = np.full((T, 2), -np.inf)
    hi = np.full((T, 2), np.inf)
    simple = (w > 0).all(1) & (np.abs(z) <= w).all(1)
    if simple.any():
        ndc = clip[simple][..., :2] / w[simple][..., None]
        lo[simple] = ndc.min(1)
        hi[simple] = ndc.max(1)
    if not simple.all():
        crossing = np.flatnonzero(~simple)
        part_lo, part_hi = lo[crossing], hi[crossing]
        near_far_extents(np.ascontiguousarray(clip[crossing]), part_lo, part_hi)
        lo[crossing], hi[crossing] = part_lo, part_hi
    size = np.array([width, height], np.float64)
    with np.errstate(invalid="ignore"):
        lo_px = np.floor((lo + 1) * size / 2 - 0.5) - 1
        hi_px = np.ceil((hi + 1) * size / 2 - 0.5) + 1
    lo_px = np.clip(np.nan_to_num(lo_px, nan=0, posinf=size.max() + 1, neginf=-1), -1, size)
    hi_px = np.clip(np.nan_to_num(hi_px, nan=-1, posinf=size.max() + 1, neginf=-1), -1, size)
    lo_px = np.maximum(lo_px, 0)
    hi_px = np.minimum(hi_px, size - 1)
    return np.stack([lo_px[:, 0], hi_px[:, 0], lo_px[:, 1], hi_px[:, 1]], 1).astype(np.int64)


def rasterize(
    pos,
    tri,
    resolution,
    *,
    outputs=OUTPUTS,
    fill_rule: str | FillRule | None = "llvmpipe",
    edge_band_px: float | None = None,
    samples: int = 1,
    sample_positions=None,
    interpolation: str = "center",
) -> ReferenceRaster:
    """Rasterize analytically in float64, with the same conventions as :func:`glraster.rasterize`.

    Parameters
    ----------
    pos, tri, resolution, outputs : as for :func:`glraster.rasterize`
    fill_rule : "llvmpipe", a :class:`~glraster.geometry.fill_rule.FillRule`, or None
        A FillRule (subpixel bits, tie rule, snapping; e.g. the one
        glraster.conformance.rules measured on a driver): coverage of unclipped triangles
        inside the viewport follows that fixed-point rule bit for bit. "llvmpipe": the
        rule of Mesa llvmpipe, :data:`~glraster.geometry.fill_rule.LLVMPIPE`. None: a
        point-in-triangle test at pixel centers, and every triangle's edges form the edge
        band.
    edge_band_px : float or None
        Half-width, in pixels, of the band around edges where coverage is not judged.
        None: the rule's :attr:`~glraster.geometry.fill_rule.FillRule.edge_band_px`
        (4/256 px for llvmpipe's and without a rule, DEFAULT_EDGE_BAND_PX).
    samples : int
        Samples per pixel S. S > 1: every sample is rasterized like a pixel center, at
        its position: the same fixed-point edge functions, offset by the sample's
        position in fixed-point steps (exact where the offsets are whole steps, as
        llvmpipe's 1/8 px ones are at 8 subpixel bits; else the float test and the edge
        band), depth and the LESS test per sample; the arrays get a sample axis after W
        as in :func:`glraster.rasterize`.
    sample_positions : (S, 2) array_like or None
        Offsets inside the pixel, pixel units, y up (a GPU raster's ``sample_positions``);
        None: the standard pattern (:data:`glraster.geometry.samples.STANDARD_POSITIONS`).
    interpolation : {"center", "centroid", "sample"}
        As for :func:`glraster.rasterize`. "sample": persp / screen (H, W, S, 3) at every
        sample. "center" / "centroid": (H, W, 3), the triangle of the pixel's
        lowest-numbered covered sample, evaluated at the pixel center, or at its
        centroid point: the pixel center when the triangle covers every sample of the
        pixel, else the lowest-numbered sample it covers (a point inside both the pixel
        and the triangle, as GL requires; llvmpipe's choice). GL allows any such point:
        judge a driver's centroid with :func:`glraster.verify.centroid.check_centroid`.

    Returns
    -------
    ReferenceRaster with float64 ``persp``/``screen``/``depth``, int32 ``tri_id``, plus
    ``edge_band`` and ``depth_tie`` (H, W) bool ((H, W, S) when multisampled).
    """
    names = validate.outputs(outputs)
    rule = fill_rule_of(fill_rule)
    if edge_band_px is None:
        edge_band_px = rule.edge_band_px if rule is not None else DEFAULT_EDGE_BAND_PX
    if not (np.isfinite(edge_band_px) and edge_band_px >= 0):
        raise ArgumentError(
            "edge_band_px", f"edge_band_px must be a finite number >= 0, got {edge_band_px!r}")
    samples = validate.samples(samples)
    interpolation = validate.interpolation(interpolation)
    positions = standard_positions(samples) if sample_positions is None \
        else validate.sample_positions(sample_positions, samples)
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution)
    shape = (height, width)
    ts = setup(pos, tri, (height, width), rule) if len(tri) else None
    info = {"backend": "reference", "renderer": "float64 (numba), fill rule "
            + ("llvmpipe" if rule == LLVMPIPE else str(rule))}
    if samples == 1:
        best_tri, band, tie = _rasterize_at(ts, rule, shape, edge_band_px, 0.5, 0.5)
        covered = best_tri >= 0
        return ReferenceRaster(
            resolution=shape, mask=covered.reshape(shape), edge_band=band.reshape(shape),
            depth_tie=tie.reshape(shape),
            triangles=ts.geometry() if ts is not None else None, info=info,
            **_values(ts, best_tri, shape, names))
    return _multisampled(ts, rule, shape, edge_band_px, names, positions, interpolation,
                         info)


def _multisampled(ts, rule, shape, edge_band_px, names, positions, interpolation, info):
    """:func:`rasterize` with S = len(positions) > 1 samples per pixel."""
    height, width = shape
    samples = len(positions)
    offsets = fixed_offsets(positions, rule.one) if rule is not None else None
    best, bands, ties, per_sample = [], [], [], []
    for k, (ox, oy) in enumerate(positions):
        moved = ts
        if ts is not None and rule is not None:
            moved = _offset_setup(ts, None if offsets is None else offsets[k])
        best_tri, band, tie = _rasterize_at(moved, rule, shape, edge_band_px, ox, oy)
        best.append(best_tri)
        bands.append(band)
        ties.append(tie)
        if interpolation == "sample" or "depth" in names:
            wanted = names if interpolation == "sample" else ("depth",)
            per_sample.append(_values(ts, best_tri, shape, wanted, ox, oy))
    tri_id = np.stack(best, axis=1).reshape(height, width, samples)
    mask = tri_id >= 0
    out = {}
    for name in ("persp", "screen", "depth"):
        if per_sample and name in per_sample[0]:
            out[name] = np.stack([v[name] for v in per_sample], axis=2)
    if interpolation != "sample" and ("persp" in names or "screen" in names):
        first = first_covered_sample(mask)
        pixel_tri = per_pixel(tri_id, first)
        point = np.full((height, width, 2), 0.5)
        if interpolation == "centroid" and ts is not None:
            point = centroid_points(ts, rule, pixel_tri, positions, offsets)
        out.update(_point_values(ts, pixel_tri, point, names))
    if "tri_id" in names:
        out["tri_id"] = tri_id.astype(np.int32)
    return ReferenceRaster(
        resolution=shape, mask=mask,
        edge_band=np.stack(bands, axis=1).reshape(height, width, samples),
        depth_tie=np.stack(ties, axis=1).reshape(height, width, samples),
        triangles=ts.geometry() if ts is not None else None, info=info,
        samples=samples, interpolation=interpolation, sample_positions=positions.copy(),
        **out)


def _offset_setup(ts: TriangleSetup, offset) -> TriangleSetup:
    """``ts`` with its fixed-point edges moved to sample at ``offset`` (dx, dy) fixed-point
    steps from the pixel center: on edge (dcdx, dcdy, c) the test c - dcdx x + dcdy y >= 1
    at (x + dx, y + dy) is (c - dcdx dx + dcdy dy) - dcdx x + dcdy y >= 1. ``offset`` None
    (not whole steps): no triangle is modeled exactly, every one gets the float test and
    the edge band."""
    from dataclasses import replace

    if offset is None:
        return replace(ts, fixed_ok=np.zeros_like(ts.fixed_ok), exact=np.zeros_like(ts.exact))
    fixed = ts.fixed.copy()
    dx, dy = int(offset[0]), int(offset[1])
    fixed[..., 2] += -fixed[..., 0] * dx + fixed[..., 1] * dy
    return replace(ts, fixed=fixed)


def _rasterize_at(ts, rule, shape, edge_band_px, ox, oy):
    """Coverage and depth test of every pixel sampled at (x + ox, y + oy): (best_tri
    (N,) int64, edge band (N,) bool, depth tie (N,) bool) over the N = H W pixels."""
    height, width = shape
    n = height * width

    # the depth test state of reference_kernels
    best_depth = np.full(n, np.inf)
    best_tri = np.full(n, -1, np.int64)
    best_error = np.zeros(n)
    others_low = np.full(n, np.inf)
    band = np.zeros(n, bool)
    if ts is not None:
        error = depth_error(ts)
        with np.errstate(divide="ignore", invalid="ignore"):
            # lambda_k = s_k w_k = e_k(p) w_k / det: the window-space barycentrics as planes
            screen_planes = ts.adj * (ts.clip[:, :, 3] / ts.det[:, None])[:, :, None]
        # Covered pixels as row spans: exact integer spans for the triangles with a
        # fixed-point setup; every bbox candidate tested in float64 for the others, which
        # also mark the edge band where coverage is not modeled exactly. The depth test's
        # result does not depend on the order of its fragments.
        fixed = np.flatnonzero(ts.fixed_ok)
        loose = np.flatnonzero(~ts.exact | ~ts.fixed_ok)
        for spans in (
            kernels.fixed_point_spans(fixed, ts.fixed, ts.bbox, rule.one if rule else 1),
            kernels.float_spans(loose, ts.adj, ts.det, ts.depth_plane, ts.bbox, ~ts.fixed_ok,
                                ~ts.exact & ~ts.culled, edge_band_px, width, band, ox, oy),
        ):
            if not len(spans[0]):
                continue                                 # nothing to test (saves a launch)
            with _PARALLEL_KERNEL:
                kernels.depth_test(*spans, ts.depth_plane, screen_planes, error, width,
                                   best_depth, best_tri, best_error, others_low,
                                   numba.get_num_threads(), ox, oy)

    covered = best_tri >= 0
    return best_tri, band, covered & (others_low <= best_depth + best_error + DEPTH_TIE)


def covers(ts: TriangleSetup, rule, t, px, py, positions, offsets) -> np.ndarray:
    """(N, S) bool: whether triangle t (N,) covers sample s of pixel (px, py) (N,) by
    itself (rasterization, before the depth test): the fixed-point test of its edges
    where it is modeled exactly, else the float test s_k >= 0 at the sample (and in front
    of the eye, inside the near and far planes)."""
    samples = len(positions)
    out = np.zeros((len(t), samples), bool)
    exact = ts.fixed_ok[t] & ts.exact[t] if offsets is not None else np.zeros(len(t), bool)
    one = rule.one if rule is not None else 1
    if exact.any():
        e = ts.fixed[t[exact]]                                  # (K, 3, 3)
        x = (one * px[exact])[:, None, None] + offsets[None, :, 0, None]  # (K, S, 1)
        y = (one * py[exact])[:, None, None] + offsets[None, :, 1, None]
        value = e[:, None, :, 2] - e[:, None, :, 0] * x + e[:, None, :, 1] * y
        out[exact] = (value >= 1).all(axis=2)
    loose = ~exact
    if loose.any():
        tl = t[loose]
        a = ts.adj[tl]                                           # (K, 3, 3)
        cx = px[loose][:, None] + positions[None, :, 0]          # (K, S)
        cy = py[loose][:, None] + positions[None, :, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (a[:, None, :, 0] * cx[..., None] + a[:, None, :, 1] * cy[..., None]
                 + a[:, None, :, 2]) / ts.det[tl][:, None, None]
            plane = ts.depth_plane[tl]
            z_ndc = 2 * (plane[:, None, 0] * cx + plane[:, None, 1] * cy + plane[:, None, 2]) - 1
        out[loose] = (s >= 0).all(axis=2) & (s.sum(axis=2) > 0) & (np.abs(z_ndc) <= 1)
    return out


def centroid_points(ts, rule, pixel_tri, positions, offsets) -> np.ndarray:
    """(H, W, 2) the reference's centroid point of each pixel's fragment of triangle
    ``pixel_tri`` (H, W) (-1: none, the center): the pixel center when the triangle
    covers all of the pixel's samples, else the position of the lowest-numbered sample it
    covers. Both lie inside the pixel and, but for a center on the boundary, inside the
    triangle, which is what GL 4.5 section 14.6.6 asks of a centroid ("must be a point
    that lies in both the pixel and in the primitive"); a covered sample is the one such
    point that is exact in the fixed point the driver decides coverage with."""
    height, width = pixel_tri.shape
    point = np.full((height, width, 2), 0.5)
    py, px = np.nonzero(pixel_tri >= 0)
    if not len(px):
        return point
    t = pixel_tri[py, px].astype(np.int64)
    cov = covers(ts, rule, t, px, py, positions, offsets)
    partial = ~cov.all(axis=1)
    first = np.argmax(cov, axis=1)
    chosen = np.where(partial[:, None], positions[first], 0.5)
    point[py, px] = chosen
    return point


def _point_values(ts, pixel_tri, point, names) -> dict:
    """persp / screen (H, W, 3) float64 of triangle ``pixel_tri`` (H, W) at the window
    point (x + point_x, y + point_y) of each pixel (formulas of kernels.values)."""
    height, width = pixel_tri.shape
    out = {n: np.zeros((height, width, 3)) for n in ("persp", "screen") if n in names}
    if ts is None:
        return out
    py, px = np.nonzero(pixel_tri >= 0)
    t = pixel_tri[py, px].astype(np.int64)
    a = ts.adj[t]
    cx = px + point[py, px, 0]
    cy = py + point[py, px, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (a[..., 0] * cx[:, None] + a[..., 1] * cy[:, None] + a[..., 2]) / ts.det[t][:, None]
        if "persp" in out:
            out["persp"][py, px] = s / ((s[:, 0] + s[:, 1]) + s[:, 2])[:, None]
        if "screen" in out:
            out["screen"][py, px] = s * ts.clip[t, :, 3]
    return out


def edge_values(ts: TriangleGeometry, t, px, py):
    """s = M^-1 (p, 1) at pixel centers (px, py) (N,) of triangles t (N,): (N, 3) float64,
    and the edge rows adj (N, 3, 3). ``ts``: a :class:`TriangleGeometry` (e.g.
    ``ReferenceRaster.triangles``) or the setup."""
    a = ts.adj[t]
    cx = px + 0.5
    cy = py + 0.5
    e = a[..., 0] * cx[:, None] + a[..., 1] * cy[:, None] + a[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = e / ts.det[t][:, None]
    return s, a


def _values(ts, best_tri, shape, names, ox=0.5, oy=0.5) -> dict:
    """The requested outputs (float64, and int32 ``tri_id``) at every pixel from the
    winning triangle ``best_tri`` (N,), computed by :func:`reference_kernels.values` at
    (x + ox, y + oy) (the center by default)."""
    height, width = shape
    n = height * width
    persp = np.zeros((n, 3) if "persp" in names else (0, 3))
    screen = np.zeros((n, 3) if "screen" in names else (0, 3))
    depth = np.ones(n if "depth" in names else 0)
    if ts is not None and (len(persp) or len(screen) or len(depth)):
        with _PARALLEL_KERNEL:
            kernels.values(best_tri, width, ts.adj, ts.det,
                           np.ascontiguousarray(ts.clip[..., 3]),
                           np.ascontiguousarray(ts.clip[..., 2]), persp, screen, depth, ox, oy)
    out = {}
    if "persp" in names:
        out["persp"] = persp.reshape(height, width, 3)
    if "screen" in names:
        out["screen"] = screen.reshape(height, width, 3)
    if "depth" in names:
        out["depth"] = depth.reshape(height, width)
    if "tri_id" in names:
        out["tri_id"] = best_tri.astype(np.int32).reshape(height, width)
    return out
