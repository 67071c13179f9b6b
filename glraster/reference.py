"""The analytic reference rasterizer: float64 NumPy, vectorized, no per-pixel Python loop.

Formulation (2D homogeneous rasterization, Olano & Greer 1997). With homogeneous window
coordinates X_i = (x_i + w_i) W/2, Y_i = (y_i + w_i) H/2 of the three clip-space vertices, the
3x3 matrix M = [[X_0 X_1 X_2], [Y_0 Y_1 Y_2], [w_0 w_1 w_2]] maps the clip-space barycentrics
of a point to its homogeneous window position. For a pixel center p = (p_x, p_y):

    s = M^-1 (p_x, p_y, 1)            s_i = lambda_i / w_p,   sum(s) = 1 / w_p
    persp_i  = s_i / sum(s)            perspective-correct (GL 4.5 eq. 14.9; seed 002 eq. 2.4.9)
    screen_i = s_i w_i                 window-space affine barycentrics (eq. 14.10)
    z_ndc    = sum(s_i z_i),  depth = z_ndc / 2 + 1/2

A point is on the triangle and in front of the eye when every s_i >= 0 (then w_p > 0), and
inside the near/far planes when -1 <= z_ndc <= 1: this handles vertices with w <= 0 and
near/far crossings without splitting triangles, and the values are those of the unclipped
triangle, as GL requires. M^-1 = adj(M) / det(M); the rows of adj(M) are the three edge
functions e_i(p), linear in window space.

Coverage of triangles whose vertices lie inside the viewport follows Mesa llvmpipe's fill
rule exactly (:func:`llvmpipe_edges`); other triangles (clipped by the near/far planes or
reaching outside the viewport, where the driver's clipper makes new float vertices) and
every triangle when ``fill_rule=None`` mark the pixel centers within ``edge_band_px`` of
their edges in ``edge_band``, where either answer is accepted.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from . import validate
from .raster import Raster

SUBPIXEL_BITS = 8  # llvmpipe: FIXED_ORDER = 8, so positions snap to 1/256 px
FIXED_ONE = 1 << SUBPIXEL_BITS
DEFAULT_EDGE_BAND_PX = 4.0 / FIXED_ONE
# Two candidates whose window depths differ by less than this are a depth tie: the GPU's
# float32 plane equations may order them either way. ~2^-17, above the depth error the
# tolerance model allows for well-shaped triangles (docs/tolerance.md).
DEPTH_TIE = 2.0**-17
CHUNK_CANDIDATES = 1 << 21


@dataclass
class ReferenceRaster(Raster):
    """A :class:`Raster` from the reference, in float64, plus where it cannot judge.

    edge_band : (H, W) bool   pixel centers within ``edge_band_px`` of an edge of a triangle
                              whose coverage is not modeled exactly: either answer accepted
    depth_tie : (H, W) bool   two triangles within DEPTH_TIE in depth: either may win
    """

    edge_band: np.ndarray | None = None
    depth_tie: np.ndarray | None = None
    setup: "TriangleSetup | None" = field(default=None, repr=False)

    @property
    def ambiguous(self) -> np.ndarray:
        """Pixels whose coverage or winning triangle may differ between correct drivers."""
        return self.edge_band | self.depth_tie


@dataclass
class TriangleSetup:
    """Per-triangle data, float64 unless noted. T triangles.

    clip   : (T, 3, 4)  clip-space vertices
    adj    : (T, 3, 3)  rows: edge functions e_i(p) = adj[i, 0] p_x + adj[i, 1] p_y + adj[i, 2]
    det    : (T,)       det(M); s = e / det
    exact  : (T,) bool  coverage modeled bit for bit (llvmpipe rule, no clipping)
    fixed  : (T, 3, 3) int64 or None   llvmpipe edges (dcdx, dcdy, c) when usable
    fixed_ok : (T,) bool  ``fixed`` holds a valid edge setup, used for coverage
    bbox   : (T, 4) int64 x0, x1, y0, y1 inclusive pixel range (x1 < x0: no pixels)
    planes_crossed : (T,) int  how many of the six clip planes (x, y, z = +-w) some vertex
             is outside of: 0 means the driver draws the triangle unclipped
    x_plane_crossed : (T,) bool  some vertex is outside x = -w or x = +w
    depth_plane : (T, 3)  window depth = a p_x + b p_y + c
    culled : (T,) bool    produces no fragment (zero area)
    """

    clip: np.ndarray
    adj: np.ndarray
    det: np.ndarray
    exact: np.ndarray
    fixed: np.ndarray
    fixed_ok: np.ndarray
    bbox: np.ndarray
    planes_crossed: np.ndarray
    x_plane_crossed: np.ndarray
    depth_plane: np.ndarray
    culled: np.ndarray


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


def llvmpipe_edges(window: np.ndarray):
    """llvmpipe's fixed-point edge setup for triangles given by float32 window positions.

    window: (T, 3, 2) float32. Returns (edges, ok): edges (T, 3, 3) int64 holding
    (dcdx, dcdy, c) per edge and ok (T,) bool (False: zero area after snapping, culled).

    Vertices snap to X = rint((x_w - 0.5) * 256) (round half to even), so pixel (i, j)
    samples the fixed-point point (256 i, 256 j). After ordering the vertices so that the
    opposite vertex lies on the positive side, per edge i -> i+1:
    dcdx = Y_i - Y_{i+1}, dcdy = X_i - X_{i+1}, c = dcdx X_i - dcdy Y_i, plus 1 when dcdx < 0
    or (dcdx == 0 and dcdy > 0). A sample is covered when c - dcdx x + dcdy y >= 1 on all
    three edges: a bottom-left fill rule in GL window coordinates.
    """
    snapped = np.rint((window - np.float32(0.5)) * np.float32(FIXED_ONE)).astype(np.int64)
    x, y = snapped[..., 0].copy(), snapped[..., 1].copy()
    side = (y[:, 0] - y[:, 1]) * (x[:, 0] - x[:, 2]) - (x[:, 0] - x[:, 1]) * (y[:, 0] - y[:, 2])
    flip = side < 0
    x[flip, 1], x[flip, 2] = x[flip, 2], x[flip, 1].copy()
    y[flip, 1], y[flip, 2] = y[flip, 2], y[flip, 1].copy()
    nxt = [1, 2, 0]
    dcdx = y - y[:, nxt]
    dcdy = x - x[:, nxt]
    c = dcdx * x - dcdy * y
    c += (dcdx < 0) | ((dcdx == 0) & (dcdy > 0))
    return np.stack([dcdx, dcdy, c], axis=-1), side != 0


def setup(pos: np.ndarray, tri: np.ndarray, resolution, fill_rule: str | None) -> TriangleSetup:
    """Per-triangle setup of the reference. pos (V, 4) float32, tri (T, 3) int32."""
    height, width = resolution
    clip32 = pos[tri]                                   # (T, 3, 4) float32
    clip = clip32.astype(np.float64)
    w = clip[..., 3]
    hom = np.stack(
        [(clip[..., 0] + w) * (width / 2), (clip[..., 1] + w) * (height / 2), w], axis=1
    )                                                   # (T, 3 rows X/Y/w, 3 vertices)
    cols = np.moveaxis(hom, 2, 1)                       # (T, vertex, xyw)
    adj = np.cross(cols[:, [1, 2, 0]], cols[:, [2, 0, 1]])  # row i = col_{i+1} x col_{i+2}
    det = np.einsum("ti,ti->t", adj[:, 0], cols[:, 0])

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
        limit = float(1 << 22)
        modeled = in_front & in_depth & (np.abs(win) < limit).all(axis=(1, 2))
    fixed = np.zeros((len(tri), 3, 3), np.int64)
    fixed_ok = np.zeros(len(tri), bool)
    if fill_rule == "llvmpipe" and modeled.any():
        fixed[modeled], fixed_ok[modeled] = llvmpipe_edges(win[modeled])
    exact = inside if fill_rule == "llvmpipe" else np.zeros(len(tri), bool)

    x, y = clip[..., 0], clip[..., 1]
    outside = np.stack([x > w, x < -w, y > w, y < -w, z > w, z < -w], -1).any(1)
    # depth = z_ndc / 2 + 1/2 with z_ndc = sum_i z_i e_i(p) / det: a plane in window space
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_plane = 0.5 * np.einsum("ti,tij->tj", z, adj) / det[:, None]
    depth_plane[:, 2] += 0.5
    # Nothing to rasterize: zero window area (det = 0), or llvmpipe culls the triangle
    # because it snaps to zero area.
    culled = (det == 0) | ~np.isfinite(depth_plane).all(1) | (exact & ~fixed_ok)
    bbox = _bounding_boxes(clip, resolution, w, z)
    bbox[culled] = (0, -1, 0, -1)
    return TriangleSetup(
        clip, adj, det, exact, fixed, fixed_ok & modeled, bbox, outside.sum(1),
        outside[:, :2].any(1),
        depth_plane, culled,
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
    for t in np.flatnonzero(~simple):
        poly = clip_polygon(clip[t])
        if len(poly) and (poly[:, 3] > 1e-12 * np.abs(poly[:, :3]).max(initial=1.0)).all():
            ndc = poly[:, :2] / poly[:, 3:4]
            lo[t], hi[t] = ndc.min(0), ndc.max(0)
        elif not len(poly):
            lo[t], hi[t] = np.inf, -np.inf  # nothing survives clipping
    size = np.array([width, height], np.float64)
    with np.errstate(invalid="ignore"):
        lo_px = np.floor((lo + 1) * size / 2 - 0.5) - 1
        hi_px = np.ceil((hi + 1) * size / 2 - 0.5) + 1
    lo_px = np.clip(np.nan_to_num(lo_px, nan=0, posinf=size.max() + 1, neginf=-1), -1, size)
    hi_px = np.clip(np.nan_to_num(hi_px, nan=-1, posinf=size.max() + 1, neginf=-1), -1, size)
    lo_px = np.maximum(lo_px, 0)
    hi_px = np.minimum(hi_px, size - 1)
    return np.stack([lo_px[:, 0], hi_px[:, 0], lo_px[:, 1], hi_px[:, 1]], 1).astype(np.int64)


def clip_polygon(vertices: np.ndarray, axes=(2,)) -> np.ndarray:
    """Sutherland-Hodgman clip of one triangle (3, 4) against -w <= c <= w for each
    coordinate index c in ``axes`` (2: near/far; (0, 1, 2): the whole view volume).
    Returns (N, 4)."""
    poly = list(vertices)
    planes = [(axis, sign) for axis in axes for sign in (1.0, -1.0)]
    for axis, sign in planes:  # keep w + c >= 0, then w - c >= 0
        out = []
        for a, b in zip(poly, poly[1:] + poly[:1]):
            da, db = a[3] + sign * a[axis], b[3] + sign * b[axis]
            if da >= 0:
                out.append(a)
            if (da >= 0) != (db >= 0):
                out.append(a + (b - a) * (da / (da - db)))
        poly = out
        if not poly:
            break
    return np.array(poly).reshape(-1, 4)


def rasterize(
    pos,
    tri,
    resolution,
    *,
    outputs=validate.OUTPUTS,
    fill_rule: str | None = "llvmpipe",
    edge_band_px: float = DEFAULT_EDGE_BAND_PX,
) -> ReferenceRaster:
    """Rasterize analytically in float64, with the same conventions as :func:`glraster.rasterize`.

    Parameters
    ----------
    pos, tri, resolution, outputs : as for :func:`glraster.rasterize`
    fill_rule : "llvmpipe" or None
        "llvmpipe": coverage of unclipped triangles inside the viewport follows Mesa
        llvmpipe's fixed-point rule bit for bit. None: a point-in-triangle test at pixel
        centers, and every triangle's edges form the edge band.
    edge_band_px : float
        Half-width, in pixels, of the band around edges where coverage is not judged.

    Returns
    -------
    ReferenceRaster with float64 ``persp``/``screen``/``depth``, int32 ``tri_id``, plus
    ``edge_band`` and ``depth_tie`` (H, W) bool.
    """
    names = validate.outputs(outputs)
    if fill_rule not in ("llvmpipe", None):
        raise ValueError(f"fill_rule must be 'llvmpipe' or None, got {fill_rule!r}")
    if not (np.isfinite(edge_band_px) and edge_band_px >= 0):
        raise ValueError(f"edge_band_px must be a finite number >= 0, got {edge_band_px!r}")
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution)

    state = _DepthBuffer(height * width)
    band = np.zeros(height * width, bool)
    ts = setup(pos, tri, (height, width), fill_rule) if len(tri) else None
    if ts is not None:
        for pix, t, depth in _prefetch(_depth_fragments(ts, band, width, edge_band_px)):
            state.test(pix, t, depth)

    covered = state.tri >= 0
    values = _values(ts, state.tri, covered, (height, width), names)
    shape = (height, width)
    return ReferenceRaster(
        resolution=shape,
        mask=covered.reshape(shape),
        edge_band=band.reshape(shape),
        depth_tie=(state.tie & covered).reshape(shape),
        setup=ts,
        info={"backend": "reference", "renderer": f"numpy float64, fill rule {fill_rule}"},
        **values,
    )


class _DepthBuffer:
    """The per-pixel depth test state: GL's LESS test in draw order, ties keep the earlier
    triangle. ``tie`` marks pixels where another triangle came within DEPTH_TIE of the
    winner. Fed chunk by chunk in draw order."""

    def __init__(self, n: int):
        self.depth = np.ones(n)                 # the cleared depth buffer
        self.tri = np.full(n, -1, np.int64)
        self.tie = np.zeros(n, bool)
        # scratch arrays, reset after each chunk (touching only the chunk's pixels)
        self._min = np.full(n, np.inf)
        self._first = np.full(n, np.iinfo(np.int64).max)
        self._count = np.zeros(n, np.int32)

    def _update(self, touched, new_depth, new_tri, new_tie):
        """Merge one chunk's winners (one entry per pixel) into the buffer."""
        old = self.depth[touched]
        wins = new_depth < old                                 # strict: LESS
        close = np.abs(new_depth - old) <= DEPTH_TIE
        had_fragment = self.tri[touched] >= 0
        self.tie[touched] = np.where(
            wins & ~close, new_tie, self.tie[touched] | (close & had_fragment) | (wins & new_tie)
        )
        self.depth[touched] = np.where(wins, new_depth, old)
        self.tri[touched] = np.where(wins, new_tri, self.tri[touched])

    def test(self, pix, t, depth):
        """Depth-test fragments (pix, t, depth) of one chunk; earlier chunks win ties."""
        # GL stores float32 depth and tests LESS against the cleared 1.0.
        keep = depth.astype(np.float32) < np.float32(1.0)
        # A fragment deeper than the stored depth by more than DEPTH_TIE can neither win
        # nor mark a tie (see _update), so occluded fragments are dropped here (exact).
        keep &= depth <= self.depth[pix] + 2 * DEPTH_TIE
        pix, t, depth = pix[keep], t[keep], depth[keep]
        if not len(pix):
            return
        multi = np.bincount(pix, minlength=len(self._min))[pix] > 1
        if not multi.any():
            # One fragment per pixel (the common case for a mesh): the chunk minimum is the
            # fragment itself, no scratch state needed. Same update as below.
            self._update(pix, depth, t, np.zeros(len(pix), bool))
            return
        # pixels hit once in this chunk: plain stores (the minimum of one value); the
        # unbuffered ufunc.at only where fragments collide
        one = ~multi
        self._min[pix[one]] = depth[one]
        self._first[pix[one]] = t[one]
        self._count[pix[one]] = 1
        pm, tm, dm = pix[multi], t[multi], depth[multi]
        np.minimum.at(self._min, pm, dm)
        chunk_min = self._min[pm]
        at_min = dm == chunk_min
        np.minimum.at(self._first, pm[at_min], tm[at_min])
        np.add.at(self._count, pm[dm <= chunk_min + DEPTH_TIE], 1)
        chunk_min = self._min[pix]
        at_min = depth == chunk_min

        touched = pix[at_min & (t == self._first[pix])]      # one entry per pixel
        self._update(touched, self._min[touched], self._first[touched],
                     self._count[touched] >= 2)
        self._min[pix] = np.inf
        self._first[pix] = np.iinfo(np.int64).max
        self._count[pix] = 0


def _candidates(ts: TriangleSetup):
    """Yield (tri, px, py) int64 arrays of (triangle, pixel) pairs inside the bounding
    boxes, in draw order, at most CHUNK_CANDIDATES at a time (a big triangle is split)."""
    starts, ends, bw, _ = _chunk_ranges(ts)
    x0, y0 = ts.bbox[:, 0], ts.bbox[:, 2]
    total = int(ends[-1]) if len(ends) else 0
    for start in range(0, total, CHUNK_CANDIDATES):
        g = np.arange(start, min(start + CHUNK_CANDIDATES, total), dtype=np.int64)
        t = np.searchsorted(ends, g, side="right")
        row, col = np.divmod(g - starts[t], bw[t])
        yield t, x0[t] + col, y0[t] + row


def _depth_fragments(ts, band, width, band_px):
    """(pixel index, triangle, window depth) of the covered fragments, chunk by chunk."""
    for t, px, py in _fragments(ts, band, width, band_px):
        yield py * width + px, t, _plane(ts.depth_plane, t, px, py)


def _prefetch(chunks):
    """Iterate ``chunks`` while a worker thread already computes the next one (the depth
    test of chunk k overlaps the fragment generation of chunk k + 1)."""
    iterator = iter(chunks)
    with ThreadPoolExecutor(1) as pool:
        future = pool.submit(next, iterator, None)
        while True:
            item = future.result()
            if item is None:
                return
            future = pool.submit(next, iterator, None)
            yield item


def _chunk_ranges(ts: TriangleSetup):
    """The candidate numbering of :func:`_candidates`: per triangle its first candidate
    (T,), bbox width and height (T,), and the total. Chunk k holds candidates
    [k CHUNK_CANDIDATES, (k + 1) CHUNK_CANDIDATES)."""
    x0, x1, y0, y1 = ts.bbox.T
    bw = np.maximum(x1 - x0 + 1, 0)
    bh = np.maximum(y1 - y0 + 1, 0)
    count = bw * bh
    ends = np.cumsum(count)
    return ends - count, ends, bw, bh


def _runs(lengths):
    """For N non-negative lengths: (owner, offset) of every element of the concatenated
    runs, owner in [0, N) and offset in [0, lengths[owner])."""
    total = int(lengths.sum())
    owner = np.repeat(np.arange(len(lengths)), lengths)
    first = np.cumsum(lengths) - lengths
    return owner, np.arange(total, dtype=np.int64) - first[owner]


def _fragments(ts: TriangleSetup, band, width, band_px):
    """Yield (tri, px, py) int64 arrays of the covered (triangle, pixel) pairs, chunk by
    chunk in draw order, with the same chunks as :func:`_candidates` (so the depth test,
    which is order independent within a chunk, gives bit-identical results).

    Triangles with an llvmpipe edge setup get their covered pixels row by row as exact
    integer spans of the fixed-point edge inequalities (no per-candidate test, empty parts
    of the bounding box cost nothing); the others are tested candidate by candidate in
    float64 (:func:`_coverage`). Pixels near the edges of triangles whose coverage is not
    exact are marked in ``band`` on the way.
    """
    starts, ends, bw, bh = _chunk_ranges(ts)
    total = int(ends[-1]) if len(ends) else 0
    x0, y0 = ts.bbox[:, 0], ts.bbox[:, 2]
    x1 = ts.bbox[:, 1]
    for lo in range(0, total, CHUNK_CANDIDATES):
        hi = min(lo + CHUNK_CANDIDATES, total)
        ta = int(np.searchsorted(ends, lo, side="right"))
        tb = int(np.searchsorted(ends, hi - 1, side="right"))
        tris = np.arange(ta, tb + 1)
        tris = tris[bw[tris] * bh[tris] > 0]
        # local candidate range [a, b) of each triangle inside this chunk
        a = np.maximum(lo - starts[tris], 0)
        b = np.minimum(hi - starts[tris], bw[tris] * bh[tris])
        out_t, out_x, out_y = [], [], []

        fixed = ts.fixed_ok[tris]
        if fixed.any():
            t, px, py = _spans(ts, tris[fixed], a[fixed], b[fixed], bw, x0, x1, y0)
            out_t.append(t), out_x.append(px), out_y.append(py)
        loose = ~fixed | ~ts.exact[tris]
        if loose.any():
            sel = tris[loose]
            owner, offset = _runs(b[loose] - a[loose])
            t = sel[owner]
            row, col = np.divmod(a[loose][owner] + offset, bw[t])
            px, py = x0[t] + col, y0[t] + row
            if band_px > 0:
                _mark_edge_band(ts, t, px, py, band, width, band_px)
            test = ~ts.fixed_ok[t]
            if test.any():
                t, px, py = t[test], px[test], py[test]
                covered = _coverage(ts, t, px, py)
                out_t.append(t[covered]), out_x.append(px[covered]), out_y.append(py[covered])
        if out_t:
            yield np.concatenate(out_t), np.concatenate(out_x), np.concatenate(out_y)


def _spans(ts: TriangleSetup, tris, a, b, bw, x0, x1, y0):
    """Covered pixels of triangles with an llvmpipe edge setup, restricted to their local
    candidate ranges [a, b) (row-major inside the bounding box). Returns (tri, px, py).

    Edge k covers pixel x of row y when c - dcdx (256 x) + dcdy (256 y) >= 1, i.e. with
    K = c + dcdy 256 y and s = 256 dcdx:  s x <= K - 1. So x <= floor((K - 1) / s) when
    s > 0, x >= -floor((K - 1) / -s) when s < 0, and every x or none when s == 0: exact
    integer arithmetic, the same inequalities as :func:`_coverage`.
    """
    r0 = a // bw[tris]
    r1 = (b - 1) // bw[tris]
    owner, offset = _runs(r1 - r0 + 1)
    t = tris[owner]
    row = r0[owner] + offset
    py = y0[t] + row
    # the chunk boundary cuts the first and last rows of a triangle
    left = x0[t] + np.where(row == r0[owner], a[owner] - row * bw[t], 0)
    right = x0[t] + np.where(row == r1[owner], b[owner] - 1 - row * bw[t], bw[t] - 1)
    right = np.minimum(right, x1[t])
    sy = py * FIXED_ONE
    for k in range(3):
        edge = ts.fixed[t, k]
        slope = edge[:, 0] * FIXED_ONE
        rhs = edge[:, 2] + edge[:, 1] * sy - 1
        pos = slope > 0
        neg = slope < 0
        with np.errstate(divide="ignore"):
            safe = np.where(slope == 0, 1, np.abs(slope))
            q = rhs // safe
        right = np.where(pos, np.minimum(right, q), right)
        left = np.where(neg, np.maximum(left, -q), left)
        # slope == 0: the whole row or nothing
        right = np.where(~pos & ~neg & (rhs < 0), left - 1, right)
    length = np.maximum(right - left + 1, 0)
    keep = length > 0
    t, py, left, length = t[keep], py[keep], left[keep], length[keep]
    owner, offset = _runs(length)
    return t[owner], left[owner] + offset, py[owner]


def _plane(plane, t, px, py):
    """Evaluate per-triangle planes (T, 3) [a, b, c] at pixel centers: a p_x + b p_y + c."""
    col = [np.ascontiguousarray(plane[:, k]) for k in range(3)]
    return np.take(col[0], t) * (px + 0.5) + np.take(col[1], t) * (py + 0.5) + np.take(col[2], t)


def edge_values(ts: TriangleSetup, t, px, py):
    """s = M^-1 (p, 1) at pixel centers: (N, 3) float64, and the edge rows adj (N, 3, 3)."""
    a = ts.adj[t]
    cx = px + 0.5
    cy = py + 0.5
    e = a[..., 0] * cx[:, None] + a[..., 1] * cy[:, None] + a[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = e / ts.det[t][:, None]
    return s, a


def _coverage(ts: TriangleSetup, t, px, py) -> np.ndarray:
    """(N,) bool: does triangle t produce a fragment at pixel (px, py)?

    Triangles with a usable llvmpipe edge setup take the fixed-point test; the others a
    float64 test of the center against the edges and the near/far planes."""
    covered = np.zeros(len(t), bool)
    fixed = ts.fixed_ok[t]
    if fixed.any():
        idx = np.flatnonzero(fixed)
        tt = t[idx]
        sx, sy = px[idx] * FIXED_ONE, py[idx] * FIXED_ONE
        inside = np.ones(len(idx), bool)
        for k in range(3):
            edge = ts.fixed[:, k]
            inside &= edge[tt, 2] - edge[tt, 0] * sx + edge[tt, 1] * sy >= 1
        covered[idx] = inside
    rest = np.flatnonzero(~fixed & ~ts.culled[t])
    if len(rest):
        tt = t[rest]
        s, _ = edge_values(ts, tt, px[rest], py[rest])
        with np.errstate(invalid="ignore"):
            z_ndc = 2 * _plane(ts.depth_plane, tt, px[rest], py[rest]) - 1
            covered[rest] = (s >= 0).all(1) & (s.sum(1) > 0) & (np.abs(z_ndc) <= 1)
    return covered


def _mark_edge_band(ts: TriangleSetup, t, px, py, band, width, band_px):
    """Mark in ``band`` the pixel centers within ``band_px`` of an edge (or of the near/far
    line) of a triangle whose coverage is not modeled exactly."""
    idx = np.flatnonzero(~ts.exact[t] & ~ts.culled[t])
    if not len(idx):
        return
    tt, qx, qy = t[idx], px[idx], py[idx]
    s, adj = edge_values(ts, tt, qx, qy)
    det = np.abs(ts.det[tt])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        # s_i |det| / |grad e_i| is the distance to edge i, positive on the triangle's side.
        grad = np.hypot(adj[..., 0], adj[..., 1])
        dist = np.where(grad > 0, s * det / grad, np.inf)
        z_ndc = 2 * _plane(ts.depth_plane, tt, qx, qy) - 1
        zg = 2 * np.hypot(ts.depth_plane[tt, 0], ts.depth_plane[tt, 1])
        dnear = np.where(zg > 0, (z_ndc + 1) / zg, np.inf)
        dfar = np.where(zg > 0, (1 - z_ndc) / zg, np.inf)
    signed = np.nan_to_num(np.concatenate([dist, dnear[:, None], dfar[:, None]], 1), nan=-np.inf)
    near_edge = (signed >= -band_px).all(1) & (np.abs(signed) < band_px).any(1)
    band[(qy * width + qx)[near_edge & (s.sum(1) > 0)]] = True


def _scatter_rows(dst: np.ndarray, rows: np.ndarray, src: np.ndarray):
    """``dst[rows] = src`` for C-contiguous (n, 3) and (N, 3) float64 arrays, as a 1-D
    assignment of 24-byte items (much faster than numpy's row-wise fancy assignment)."""
    item = np.dtype((np.void, dst.itemsize * dst.shape[1]))
    dst.view(item)[:, 0][rows] = np.ascontiguousarray(src).view(item)[:, 0]


VALUE_THREADS = 2
PARALLEL_PIXELS = 1 << 17


def _values_part(ts, cols, best_tri, pix, width, persp, screen, depth):
    """Fill the rows ``pix`` of the (n, 3) / (n,) outputs that are not None."""
    t = best_tri[pix]
    py, px = np.divmod(pix, width)
    cx, cy = px + 0.5, py + 0.5
    det = np.take(ts.det, t)
    s = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):
            a, b, c = cols["adj"][k]
            e = np.take(a, t) * cx
            e += np.take(b, t) * cy
            e += np.take(c, t)
            s.append(e / det)
        total = s[0] + s[1]
        total += s[2]
        rows = np.empty((len(pix), 3))
        if persp is not None:
            for k in range(3):
                np.divide(s[k], total, out=rows[:, k])
            _scatter_rows(persp, pix, rows)
        if screen is not None:
            for k in range(3):
                np.multiply(s[k], np.take(cols["w"][k], t), out=rows[:, k])
            _scatter_rows(screen, pix, rows)
        if depth is not None:
            acc = s[0] * np.take(cols["z"][0], t)
            acc += s[1] * np.take(cols["z"][1], t)
            acc += s[2] * np.take(cols["z"][2], t)
            depth[pix] = acc * 0.5 + 0.5


def _values(ts, best_tri, covered, resolution, names) -> dict:
    """The requested outputs at every pixel from the winning triangle (float64).

    Computed per barycentric channel on 1-D arrays (np.take gathers, no reductions over a
    short axis): the same operations in the same order as :func:`edge_values`,
    s = (A p_x + B p_y + C) / det, persp = s / ((s_0 + s_1) + s_2), so the values are
    bit-identical to evaluating those formulas row by row. Large images are split in
    halves evaluated by two threads (numpy releases the GIL in these loops).
    """
    height, width = resolution
    n = height * width
    out = {}
    pix = np.flatnonzero(covered)
    persp = np.zeros((n, 3)) if "persp" in names else None
    screen = np.zeros((n, 3)) if "screen" in names else None
    depth = np.ones(n) if "depth" in names else None
    if ts is not None and len(pix):
        cols = {
            "adj": [[np.ascontiguousarray(ts.adj[:, k, j]) for j in range(3)] for k in range(3)],
            "w": [np.ascontiguousarray(ts.clip[:, k, 3]) for k in range(3)],
            "z": [np.ascontiguousarray(ts.clip[:, k, 2]) for k in range(3)],
        }
        parts = np.array_split(pix, VALUE_THREADS if len(pix) >= PARALLEL_PIXELS else 1)
        if len(parts) > 1:
            with ThreadPoolExecutor(len(parts)) as pool:
                list(pool.map(lambda part: _values_part(ts, cols, best_tri, part, width,
                                                        persp, screen, depth), parts))
        else:
            _values_part(ts, cols, best_tri, pix, width, persp, screen, depth)
    if persp is not None:
        out["persp"] = persp.reshape(height, width, 3)
    if screen is not None:
        out["screen"] = screen.reshape(height, width, 3)
    if depth is not None:
        out["depth"] = depth.reshape(height, width)
    if "tri_id" in names:
        out["tri_id"] = best_tri.astype(np.int32).reshape(height, width)
    return out
