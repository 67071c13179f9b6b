"""Exact area coverage: the float64 area of each pixel that the triangles cover.

This is the limit that every supersampling and multisampling pattern approaches as its
sample count grows (the box-filtered coverage), and the truth the antialiasing study
(glraster.studies.antialias) measures every method against.

The geometry, per triangle, all in float64 (the float32 positions the GPU is given,
promoted exactly):

1. Clip the triangle in clip space against the whole view volume -w <= x, y, z <= w
   (GL 4.5 core section 13.7; Sutherland-Hodgman, glraster.geometry.clipping), **before**
   the divide by w. What survives has w >= max(|x|, |y|, |z|) >= 0, so parts behind the
   eye (w <= 0) and beyond the near and far planes are gone, and what is left projects
   into the viewport. A polygon vertex with w = 0 can only be the clip-space origin, which
   lies in the triangle's plane only when the triangle projects to a line (zero area).
2. Divide by w and apply the viewport transform (section 13.8):
   x_w = (x/w + 1) W/2, y_w = (y/w + 1) H/2, z_w = (z/w)/2 + 1/2. The result is a convex
   polygon of at most 9 vertices; window depth is an affine function of (x_w, y_w) on it.
3. Clip that polygon against each pixel square [i, i+1] x [j, j+1] of its bounding box
   (Sutherland-Hodgman against the four sides, in pixel-local coordinates so that the
   float64 rounding is relative to the pixel, not to the viewport) and take the area by
   the shoelace formula.

Overlapping triangles. :func:`area_coverage` is the area of the **union** of all triangles
in each pixel (what a sample pattern's covered fraction converges to: a sample is covered
when any triangle covers it, whatever the depth order). :func:`visible_area` splits that
area among the triangles by the depth test glraster uses (LESS in draw order, ties keep the
earlier triangle): the area of each triangle that is in front, per pixel. For opaque
triangles that do not intersect this is the visible-surface area; intersecting triangles
are split along their line of equal depth. Pixels that only one triangle touches take its
clipped area directly; pixels that several touch are decomposed into vertical slabs between
every vertex abscissa and every crossing of two edges or equal-depth lines: inside a slab
no two of those segments cross, so the length of each triangle's visible part along a
vertical line is linear in x and the slab's midpoint gives its area exactly.

Accuracy: against an independent clipper (shapely, on triangles clipped in exact rational
arithmetic) the difference is below 1e-12 of a pixel's area on random, sliver, perspective
and near-clipped triangles (tests/reference/test_area.py). Coplanar triangles that overlap
(z-fighting) are ordered by their float64 depth planes, as no driver promises anything
there; their union is exact all the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster import jit
from glraster import validate
from glraster.errors import ArgumentError
from glraster.geometry.clipping import clip_to_planes

__all__ = ["AreaFragments", "area_coverage", "visible_area", "window_polygons"]

_compiled = jit.njit(nogil=True, error_model="numpy")

#: Most vertices of a triangle clipped by the six planes of the view volume.
MAX_POLYGON = 9
#: Most vertices of that polygon clipped by the four sides of a pixel square.
MAX_PIXEL_POLYGON = MAX_POLYGON + 4


# --------------------------------------------------------------------------- kernels


@_compiled
def _window_polygons(clip, height, width, poly_out, counts, planes):
    """Clip each triangle (T, 3, 4) to the view volume and project it: poly_out (T, 9, 2)
    window (x_w, y_w), counter-clockwise; counts (T,) its vertex count (0: nothing left
    or zero area); planes (T, 3) its window depth z_w = a x_w + b y_w + c."""
    poly = np.empty((MAX_POLYGON, 4))
    scratch = np.empty((MAX_POLYGON, 4))
    zw = np.empty(MAX_POLYGON)
    for t in range(clip.shape[0]):
        counts[t] = 0
        n = clip_to_planes(clip[t], 0, poly, scratch)
        if n < 3:
            continue
        degenerate = False
        for i in range(n):
            w = poly[i, 3]
            if not w > 0.0:
                degenerate = True
                break
            # |x| <= w after clipping, up to rounding of the clipper: clamp to the viewport
            x = min(max(poly[i, 0] / w, -1.0), 1.0)
            y = min(max(poly[i, 1] / w, -1.0), 1.0)
            poly_out[t, i, 0] = (x + 1.0) * (0.5 * width)
            poly_out[t, i, 1] = (y + 1.0) * (0.5 * height)
            zw[i] = (poly[i, 2] / w) * 0.5 + 0.5
        if degenerate:
            continue
        # signed area; the fan triangle of largest |area| fixes the depth plane
        area2 = 0.0
        best, best_i = 0.0, 1
        x0, y0 = poly_out[t, 0, 0], poly_out[t, 0, 1]
        for i in range(1, n - 1):
            cross = ((poly_out[t, i, 0] - x0) * (poly_out[t, i + 1, 1] - y0)
                     - (poly_out[t, i + 1, 0] - x0) * (poly_out[t, i, 1] - y0))
            area2 += cross
            if abs(cross) > best:
                best, best_i = abs(cross), i
        if area2 == 0.0 or best == 0.0:
            continue
        # plane through vertices 0, best_i, best_i + 1
        i1, i2 = best_i, best_i + 1
        ux = poly_out[t, i1, 0] - poly_out[t, 0, 0]
        uy = poly_out[t, i1, 1] - poly_out[t, 0, 1]
        uz = zw[i1] - zw[0]
        vx = poly_out[t, i2, 0] - poly_out[t, 0, 0]
        vy = poly_out[t, i2, 1] - poly_out[t, 0, 1]
        vz = zw[i2] - zw[0]
        det = ux * vy - vx * uy
        a = (uz * vy - vz * uy) / det
        b = (ux * vz - vx * uz) / det
        planes[t, 0] = a
        planes[t, 1] = b
        planes[t, 2] = zw[0] - a * poly_out[t, 0, 0] - b * poly_out[t, 0, 1]
        if area2 < 0.0:                       # back-facing: GL draws it, reverse the order
            for i in range(n // 2):
                j = n - 1 - i
                for c in range(2):
                    tmp = poly_out[t, i, c]
                    poly_out[t, i, c] = poly_out[t, j, c]
                    poly_out[t, j, c] = tmp
                tmp = zw[i]
                zw[i] = zw[j]
                zw[j] = tmp
        counts[t] = n


@_compiled
def _clip_axis(src, n, dst, axis, bound, keep_below):
    """Sutherland-Hodgman of polygon src[:n] (2D) against coordinate ``axis`` <= bound
    (keep_below) or >= bound; writes dst, returns the new count."""
    out = 0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        da = bound - src[i, axis] if keep_below else src[i, axis] - bound
        db = bound - src[j, axis] if keep_below else src[j, axis] - bound
        if da >= 0.0:
            dst[out, 0] = src[i, 0]
            dst[out, 1] = src[i, 1]
            out += 1
        if (da >= 0.0) != (db >= 0.0):
            s = da / (da - db)
            dst[out, 0] = src[i, 0] + (src[j, 0] - src[i, 0]) * s
            dst[out, 1] = src[i, 1] + (src[j, 1] - src[i, 1]) * s
            # land exactly on the side that was cut
            dst[out, axis] = bound
            out += 1
    return out


@_compiled
def _clip_to_pixel(poly, n, px, py, out, scratch):
    """poly[:n] (window coordinates) clipped to the square [px, px+1] x [py, py+1], in
    coordinates local to the pixel (its lower-left corner at 0); into out, returns the
    count."""
    for i in range(n):
        scratch[i, 0] = poly[i, 0] - px
        scratch[i, 1] = poly[i, 1] - py
    m = _clip_axis(scratch, n, out, 0, 0.0, False)
    if m == 0:
        return 0
    m = _clip_axis(out, m, scratch, 0, 1.0, True)
    if m == 0:
        return 0
    m = _clip_axis(scratch, m, out, 1, 0.0, False)
    if m == 0:
        return 0
    m = _clip_axis(out, m, scratch, 1, 1.0, True)
    for i in range(m):
        out[i, 0] = scratch[i, 0]
        out[i, 1] = scratch[i, 1]
    return m


@_compiled
def _shoelace(p, n):
    s = 0.0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        s += p[i, 0] * p[j, 1] - p[j, 0] * p[i, 1]
    return 0.5 * s


@_compiled
def _bbox(poly, n, height, width):
    """Pixel range (x0, x1, y0, y1), half-open, of polygon poly[:n] in the viewport."""
    xmin, xmax, ymin, ymax = np.inf, -np.inf, np.inf, -np.inf
    for i in range(n):
        xmin = min(xmin, poly[i, 0])
        xmax = max(xmax, poly[i, 0])
        ymin = min(ymin, poly[i, 1])
        ymax = max(ymax, poly[i, 1])
    x0 = max(int(np.floor(xmin)), 0)
    y0 = max(int(np.floor(ymin)), 0)
    x1 = min(int(np.ceil(xmax)), width)
    y1 = min(int(np.ceil(ymax)), height)
    return x0, x1, y0, y1


@_compiled
def _count_fragments(polys, counts, height, width):
    total = 0
    for t in range(polys.shape[0]):
        if counts[t] == 0:
            continue
        x0, x1, y0, y1 = _bbox(polys[t], counts[t], height, width)
        total += max(x1 - x0, 0) * max(y1 - y0, 0)
    return total


@_compiled
def _fragments(polys, counts, height, width, pixel, tri_id, area):
    """Per triangle and pixel of its bounding box, the clipped area; keeps those > 0.
    Returns how many were written (pixel = y W + x, tri_id, area)."""
    out = np.empty((MAX_PIXEL_POLYGON, 2))
    scratch = np.empty((MAX_PIXEL_POLYGON, 2))
    f = 0
    for t in range(polys.shape[0]):
        n = counts[t]
        if n == 0:
            continue
        poly = polys[t]
        x0, x1, y0, y1 = _bbox(poly, n, height, width)
        for py in range(y0, y1):
            for px in range(x0, x1):
                m = _clip_to_pixel(poly, n, px, py, out, scratch)
                if m < 3:
                    continue
                a = _shoelace(out, m)
                if a > 0.0:
                    pixel[f] = py * width + px
                    tri_id[f] = t
                    area[f] = min(a, 1.0)
                    f += 1
    return f


# Cut lines inside a pixel: rows (A, B, C, x0, y0, x1, y1, kind) of the line A x + B y + C = 0;
# kind SEGMENT: only its part from (x0, y0) to (x1, y1) counts; kind LINE: all of it.
SEGMENT, LINE = 0.0, 1.0
# Crossings are kept when they lie within this margin of a segment or of the square (the
# margin only adds breakpoints, which never changes the result; it keeps a crossing at a
# segment's end that rounding would push just outside).
_MARGIN = 1e-9


@_compiled
def _set_segment(lines, r, x0, y0, x1, y1):
    a = y1 - y0
    b = x0 - x1
    lines[r, 0], lines[r, 1], lines[r, 2] = a, b, -(a * x0 + b * y0)
    lines[r, 3], lines[r, 4], lines[r, 5], lines[r, 6] = x0, y0, x1, y1
    lines[r, 7] = SEGMENT


@_compiled
def _on_segment(lines, r, x, y):
    if lines[r, 7] == LINE:
        return True
    dx, dy = lines[r, 5] - lines[r, 3], lines[r, 6] - lines[r, 4]
    s = ((x - lines[r, 3]) * dx + (y - lines[r, 4]) * dy) / (dx * dx + dy * dy)
    return -_MARGIN <= s <= 1.0 + _MARGIN


@_compiled
def _split_pixel(local, sizes, depth, visible):
    """Visible area of each of k polygons local[i, :sizes[i]] (convex, counter-clockwise,
    inside the unit square) with depth planes depth (k, 3) in local coordinates: visible
    (k,) gets the area where polygon i is in front (LESS in order, ties keep the lower
    index).

    Vertical slabs between all breakpoints: the vertices' abscissae and the crossings,
    inside the square, of the cut lines (the polygons' edges, the square's sides and the
    lines of equal depth of two polygons whose depth ranges overlap). Inside a slab no two
    cuts cross, so each visible length along a vertical line is linear in x and the slab's
    midpoint gives its area exactly."""
    k = local.shape[0]
    zmin = np.empty(k)
    zmax = np.empty(k)
    for i in range(k):
        zmin[i], zmax[i] = np.inf, -np.inf
        for v in range(sizes[i]):
            z = depth[i, 0] * local[i, v, 0] + depth[i, 1] * local[i, v, 1] + depth[i, 2]
            zmin[i] = min(zmin[i], z)
            zmax[i] = max(zmax[i], z)
    # A polygon behind every point of one that covers the whole square is hidden.
    cover_z = np.inf
    for i in range(k):
        if sizes[i] == 4 and _shoelace(local[i], 4) == 1.0:
            cover_z = min(cover_z, zmax[i])
    live = np.empty(k, np.bool_)
    for i in range(k):
        live[i] = not zmin[i] > cover_z
        visible[i] = 0.0

    n_max = 4 + k * MAX_PIXEL_POLYGON + k * (k - 1) // 2
    lines = np.empty((n_max, 8))
    _set_segment(lines, 0, 0.0, 0.0, 1.0, 0.0)
    _set_segment(lines, 1, 1.0, 0.0, 1.0, 1.0)
    _set_segment(lines, 2, 1.0, 1.0, 0.0, 1.0)
    _set_segment(lines, 3, 0.0, 1.0, 0.0, 0.0)
    n_lines = 4
    n_vertices = 0
    for i in range(k):
        if not live[i]:
            continue
        n_vertices += sizes[i]
        for v in range(sizes[i]):
            w = v + 1 if v + 1 < sizes[i] else 0
            x0, y0 = local[i, v, 0], local[i, v, 1]
            x1, y1 = local[i, w, 0], local[i, w, 1]
            if ((x0 == x1 and (x0 == 0.0 or x0 == 1.0))
                    or (y0 == y1 and (y0 == 0.0 or y0 == 1.0))):
                continue                       # on a side of the square: already a cut
            _set_segment(lines, n_lines, x0, y0, x1, y1)
            n_lines += 1
    pair_a = np.empty(k * (k - 1) // 2, np.int64)
    pair_b = np.empty(k * (k - 1) // 2, np.int64)
    pair_line = np.empty(k * (k - 1) // 2, np.int64)
    n_pairs = 0
    for i in range(k):
        for j in range(i + 1, k):
            if not (live[i] and live[j]) or zmax[i] < zmin[j] or zmax[j] < zmin[i]:
                continue                       # disjoint depth ranges: the order is fixed
            a = depth[i, 0] - depth[j, 0]
            b = depth[i, 1] - depth[j, 1]
            if a == 0.0 and b == 0.0:
                continue
            lines[n_lines, 0] = a
            lines[n_lines, 1] = b
            lines[n_lines, 2] = depth[i, 2] - depth[j, 2]
            lines[n_lines, 7] = LINE
            pair_a[n_pairs], pair_b[n_pairs], pair_line[n_pairs] = i, j, n_lines
            n_pairs += 1
            n_lines += 1

    xs = np.empty(2 + n_vertices + n_lines * (n_lines - 1) // 2)
    xs[0], xs[1] = 0.0, 1.0
    nx = 2
    for i in range(k):
        if live[i]:
            for v in range(sizes[i]):
                xs[nx] = local[i, v, 0]
                nx += 1
    for p in range(n_lines):
        a1, b1, c1 = lines[p, 0], lines[p, 1], lines[p, 2]
        for q in range(p + 1, n_lines):
            a2, b2, c2 = lines[q, 0], lines[q, 1], lines[q, 2]
            det = a1 * b2 - a2 * b1
            if det == 0.0:
                continue
            x = (b1 * c2 - b2 * c1) / det
            y = (c1 * a2 - c2 * a1) / det
            if (0.0 < x < 1.0 and -_MARGIN <= y <= 1.0 + _MARGIN
                    and _on_segment(lines, p, x, y) and _on_segment(lines, q, x, y)):
                xs[nx] = x
                nx += 1
    xs = np.sort(xs[:nx])

    lo = np.empty(k)
    hi = np.empty(k)
    present = np.empty(k, np.bool_)
    ys = np.empty(2 * k + n_pairs)
    for s in range(nx - 1):
        xa, xb = xs[s], xs[s + 1]
        dx = xb - xa
        if not dx > 0.0:
            continue
        xm = 0.5 * (xa + xb)
        ny = 0
        for i in range(k):
            lo[i], hi[i] = np.inf, -np.inf
            present[i] = False
            if not live[i]:
                continue
            n = sizes[i]
            for v in range(n):
                w = v + 1 if v + 1 < n else 0
                xv, xw = local[i, v, 0], local[i, w, 0]
                if xv != xw and ((xv <= xm <= xw) or (xw <= xm <= xv)):
                    t = (xm - xv) / (xw - xv)
                    y = local[i, v, 1] + (local[i, w, 1] - local[i, v, 1]) * t
                    lo[i] = min(lo[i], y)
                    hi[i] = max(hi[i], y)
            present[i] = hi[i] > lo[i]
            if present[i]:
                ys[ny] = lo[i]
                ys[ny + 1] = hi[i]
                ny += 2
        # the equal-depth line of two polygons present here cuts the column too
        for d in range(n_pairs):
            i, j, r = pair_a[d], pair_b[d], pair_line[d]
            if not (present[i] and present[j]) or lines[r, 1] == 0.0:
                continue
            y = -(lines[r, 0] * xm + lines[r, 2]) / lines[r, 1]
            if max(lo[i], lo[j]) < y < min(hi[i], hi[j]):
                ys[ny] = y
                ny += 1
        if ny == 0:
            continue
        order = np.sort(ys[:ny])
        for r in range(ny - 1):
            ya, yb = order[r], order[r + 1]
            if not yb > ya:
                continue
            ym = 0.5 * (ya + yb)
            front = -1
            best = np.inf
            for i in range(k):
                if present[i] and lo[i] <= ym <= hi[i]:
                    z = depth[i, 0] * xm + depth[i, 1] * ym + depth[i, 2]
                    if z < best:
                        best, front = z, i
            if front >= 0:
                visible[front] += (yb - ya) * dx


@_compiled
def _resolve_shared(polys, counts, planes, width, pixel, tri_id, area, starts):
    """For each run starts[g]:starts[g+1] of fragments sharing a pixel (sorted by pixel,
    then triangle), replace their areas by the visible areas of :func:`_split_pixel`."""
    local = np.empty((1, MAX_PIXEL_POLYGON, 2))
    scratch = np.empty((MAX_PIXEL_POLYGON, 2))
    for g in range(starts.shape[0] - 1):
        s, e = starts[g], starts[g + 1]
        k = e - s
        if k < 2:
            continue
        if local.shape[0] < k:
            local = np.empty((k, MAX_PIXEL_POLYGON, 2))
        sizes = np.empty(k, np.int64)
        depth = np.empty((k, 3))
        py, px = pixel[s] // width, pixel[s] % width
        for i in range(k):
            t = tri_id[s + i]
            sizes[i] = _clip_to_pixel(polys[t], counts[t], px, py, local[i], scratch)
            depth[i, 0] = planes[t, 0]
            depth[i, 1] = planes[t, 1]
            depth[i, 2] = planes[t, 2] + planes[t, 0] * px + planes[t, 1] * py
        visible = np.empty(k)
        _split_pixel(local[:k], sizes, depth, visible)
        for i in range(k):
            area[s + i] = visible[i]


# --------------------------------------------------------------------------- public API


@dataclass(frozen=True)
class AreaFragments:
    """The visible area of each triangle in each pixel it reaches (sparse, F fragments,
    sorted by pixel then triangle; fragments of zero visible area are dropped).

    y, x     : (F,) int64   the pixel (row 0 at the bottom, GL window convention)
    tri_id   : (F,) int32   the triangle (index into ``tri``)
    area     : (F,) float64 the area of the pixel where that triangle is in front, in
               [0, 1] (pixel areas); per pixel they sum to :attr:`coverage`
    resolution : (H, W)
    """

    y: np.ndarray
    x: np.ndarray
    tri_id: np.ndarray
    area: np.ndarray
    resolution: tuple[int, int]

    @property
    def coverage(self) -> np.ndarray:
        """(H, W) float64: the covered area of each pixel (the union of the triangles)."""
        height, width = self.resolution
        out = np.zeros(height * width)
        np.add.at(out, self.y * width + self.x, self.area)
        return np.minimum(out, 1.0).reshape(height, width)

    def resolve(self, tri_values, background=0.0) -> np.ndarray:
        """The exact box-filtered image of flat-shaded triangles.

        Args:
            tri_values: (T,) or (T, C) a value (colour) per triangle.
            background: scalar or (C,) the value where no triangle is.

        Returns:
            (H, W) or (H, W, C) float64: sum over triangles of visible area x value, plus
            (1 - coverage) x background.
        """
        height, width = self.resolution
        values = np.asarray(tri_values, dtype=np.float64)
        if values.ndim not in (1, 2):
            raise ArgumentError(
                "tri_values", f"tri_values must have shape (T,) or (T, C), got {values.shape}")
        if len(self.tri_id) and int(self.tri_id.max()) >= len(values):
            raise ArgumentError("tri_values", f"tri_values has {len(values)} rows, but triangle "
                                              f"{int(self.tri_id.max())} covers pixels")
        flat = values.reshape(len(values), -1)
        channels = flat.shape[1]
        out = np.zeros((height * width, channels))
        index = self.y * width + self.x
        for c in range(channels):
            np.add.at(out[:, c], index, self.area * flat[self.tri_id, c])
        bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (channels,))
        out += (1.0 - self.coverage.reshape(-1, 1)) * bg
        shape = (height, width) if values.ndim == 1 else (height, width, channels)
        return out.reshape(shape)


def window_polygons(pos, tri, resolution):
    """Each triangle clipped to the view volume in clip space and projected.

    Args:
        pos: (V, 4) clip-space positions (converted to float32 once, as the GPU gets them,
            then evaluated in float64).
        tri: (T, 3) integer vertex indices.
        resolution: (H, W).

    Returns:
        ``(polygons, counts, planes)``: polygons (T, 9, 2) float64 window (x_w, y_w) of
        each convex polygon, counter-clockwise, its first ``counts[t]`` rows valid;
        counts (T,) int64, 0 where nothing of the triangle is visible or its projection
        has zero area; planes (T, 3) float64, window depth z_w = a x_w + b y_w + c.
    """
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution)
    clip = pos[tri].astype(np.float64)
    t = len(tri)
    polygons = np.zeros((t, MAX_POLYGON, 2))
    counts = np.zeros(t, np.int64)
    planes = np.zeros((t, 3))
    if t:
        _window_polygons(clip, height, width, polygons, counts, planes)
    return polygons, counts, planes


def visible_area(pos, tri, resolution) -> AreaFragments:
    """The exact visible area of every triangle in every pixel (float64).

    Args:
        pos: (V, 4) clip-space positions. tri: (T, 3) vertex indices. resolution: (H, W).

    Returns:
        :class:`AreaFragments`: per pixel and triangle the area (in pixel areas) where that
        triangle is in front by the depth test (LESS in draw order, ties keep the earlier
        triangle); their sum per pixel is :func:`area_coverage`.
    """
    height, width = validate.resolution(resolution)
    polygons, counts, planes = window_polygons(pos, tri, resolution)
    bound = _count_fragments(polygons, counts, height, width)
    pixel = np.empty(bound, np.int64)
    tri_id = np.empty(bound, np.int32)
    area = np.empty(bound)
    f = _fragments(polygons, counts, height, width, pixel, tri_id, area)
    pixel, tri_id, area = pixel[:f], tri_id[:f], area[:f]
    order = np.lexsort((tri_id, pixel))
    pixel, tri_id, area = pixel[order], tri_id[order], area[order]
    if f:
        change = np.flatnonzero(np.diff(pixel)) + 1
        starts = np.concatenate([[0], change, [f]]).astype(np.int64)
        _resolve_shared(polygons, counts, planes, width, pixel, tri_id, area, starts)
    keep = area > 0.0
    pixel, tri_id, area = pixel[keep], tri_id[keep], area[keep]
    return AreaFragments(pixel // width, pixel % width, tri_id, area, (height, width))


def area_coverage(pos, tri, resolution) -> np.ndarray:
    """The exact area of each pixel covered by the triangles (float64).

    Args:
        pos: (V, 4) clip-space positions (converted to float32 once, as the GPU gets them;
            the geometry is then evaluated in float64).
        tri: (T, 3) integer vertex indices.
        resolution: (H, W).

    Returns:
        (H, W) float64 in [0, 1], row 0 at the bottom: the area of the pixel square covered
        by the union of the triangles after clipping to the view volume (near and far
        planes, w <= 0 removed before the divide). The limit of the covered fraction of any
        supersampling or multisampling pattern as its sample count grows.
    """
    return visible_area(pos, tri, resolution).coverage
