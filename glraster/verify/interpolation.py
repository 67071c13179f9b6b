"""Judging where a multisampled fragment's barycentrics were evaluated, by what GL requires.

GLSL 4.50 section 4.5 (Interpolation Qualifiers) leaves the point to the implementation:
without a qualifier the value "may be interpolated anywhere within the pixel"; with
``centroid`` it "must be interpolated at a location that lies in both the pixel and in the
primitive being rendered, or at one of the pixel's samples that falls within the
primitive"; with ``sample`` it must be taken at each sample's own location (that case is a
plain per-sample comparison, :func:`glraster.verify.compare.compare`). So one reference
point cannot judge a driver's "center" or "centroid" values; the point itself can:

- the window-space barycentrics b (``screen``) of a point p of triangle (v_0, v_1, v_2)
  give p back, p = sum_i b_i v_i (the weights sum to 1); from ``persp`` alone,
  b_i = persp_i w_i / sum_j persp_j w_j (GL 4.5 eq. 14.9 inverted);
- "center": p must lie in the pixel square [x, x + 1] x [y, y + 1];
- "centroid": p must lie in the pixel and in the triangle (every b_i >= 0);
- both: ``persp`` must be the perspective-correct value at that same p,
  persp_i = (b_i / w_i) / sum_j (b_j / w_j), within the error model with the screen
  error carried (ErrorModel.persp_from_screen), so a driver that evaluates 1/w at one
  point and the attributes at another fails.

Tolerances: the per-pixel bound on each b_i (:func:`value_tolerance`) moves p by at most
sum_i tol_i |v_i - p| (a perturbation of weights that sum to 1); b_i >= -tol_i.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from glraster.errors import ArgumentError
from glraster.geometry.triangles import TriangleGeometry
from glraster.verify.tolerance import ErrorModel, value_tolerance


@dataclass
class PointCheck:
    """Result of :func:`check_point` over the judged pixels.

    pixels      : pixels judged
    outside_pixel : the implied point lies outside the pixel square (beyond tolerance)
    outside_triangle : ("centroid") the implied point lies outside the triangle
    persp_inconsistent : persp is not the perspective-correct value at the implied point
    worst_ratio : largest violation / tolerance (<= 1 passes)
    offset      : (K, 2) implied points relative to the pixel's lower-left corner
    """

    pixels: int = 0
    outside_pixel: int = 0
    outside_triangle: int = 0
    persp_inconsistent: int = 0
    worst_ratio: float = 0.0
    offset: np.ndarray | None = None

    @property
    def failures(self) -> int:
        """Pixels that break the spec's condition in some way."""
        return int(self._bad.sum()) if self._bad is not None else 0

    _bad: np.ndarray | None = None


def window_vertices(triangles: TriangleGeometry, resolution) -> np.ndarray:
    """(T, 3, 2) float64 window positions of the triangles' vertices (w > 0 assumed)."""
    height, width = resolution
    clip = triangles.clip
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = clip[..., :2] / clip[..., 3:4]
    return (ndc + 1) * np.array([width, height]) / 2


def check_point(triangles: TriangleGeometry, tri_id: np.ndarray, judged: np.ndarray,
                persp=None, screen=None, interpolation: str = "centroid",
                model: ErrorModel = ErrorModel()) -> PointCheck:
    """Check per-pixel barycentrics against GLSL's condition for ``interpolation``.

    triangles : the reference's TriangleGeometry; tri_id (H, W) int: the triangle whose
    values the pixel holds; judged (H, W) bool: the pixels to judge (covered, same
    triangle on both sides, not ambiguous, every vertex in front of the eye);
    persp / screen : (H, W, 3) GPU values (at least one).
    """
    if persp is None and screen is None:
        raise ArgumentError("persp", "check_point needs persp or screen")
    ys, xs = np.nonzero(judged)
    out = PointCheck(pixels=len(xs))
    if not len(xs):
        out.offset = np.zeros((0, 2))
        out._bad = np.zeros(0, bool)
        return out
    t = tri_id[ys, xs].astype(np.int64)
    resolution = tri_id.shape
    verts = window_vertices(triangles, resolution)[t]            # (K, 3, 2)
    w = triangles.clip[t, :, 3]                                   # (K, 3)
    names = tuple(n for n, a in (("persp", persp), ("screen", screen)) if a is not None)
    carried = replace(model, persp_from_screen=True)
    tol = value_tolerance(triangles, np.where(judged, tri_id, -1), names, carried)
    if screen is not None:
        b = screen[ys, xs].astype(np.float64)
        tol_b = tol.screen[ys, xs]
    else:
        q = persp[ys, xs].astype(np.float64) * w
        b = q / q.sum(axis=1, keepdims=True)
        # persp_i w_i / sum: relative error of persp carried, scaled by w_i / sum
        tol_b = tol.persp[ys, xs] * np.abs(w) / np.abs(q.sum(axis=1, keepdims=True))
    total = b.sum(axis=1, keepdims=True)
    point = (b[..., None] * verts).sum(axis=1) / total            # (K, 2)
    reach = (tol_b[..., None] * np.abs(verts - point[:, None, :])).sum(axis=1).max(axis=1)
    reach = reach + 1e-9                                          # float64 rounding of p
    corner = np.stack([xs, ys], axis=1)
    local = point - corner
    beyond = np.maximum(np.maximum(-local, local - 1).max(axis=1), 0.0)
    ratio = beyond / reach
    bad = ratio > 1
    out.outside_pixel = int(bad.sum())
    if interpolation == "centroid":
        below = np.maximum(-b, 0.0) / (tol_b + 1e-12)
        outside = below.max(axis=1) > 1
        out.outside_triangle = int(outside.sum())
        ratio = np.maximum(ratio, below.max(axis=1))
        bad |= outside
    if persp is not None and screen is not None:
        q = b / w
        expected = q / q.sum(axis=1, keepdims=True)
        err = np.abs(persp[ys, xs].astype(np.float64) - expected)
        persp_ratio = (err / tol.persp[ys, xs]).max(axis=1)
        inconsistent = persp_ratio > 1
        out.persp_inconsistent = int(inconsistent.sum())
        ratio = np.maximum(ratio, persp_ratio)
        bad |= inconsistent
    out.worst_ratio = float(np.nan_to_num(ratio, nan=np.inf).max())
    bad |= ~np.isfinite(ratio)
    out.offset = local
    out._bad = bad
    return out
