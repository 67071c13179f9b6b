"""Comparing a GPU raster with the reference: coverage, triangle ids and values."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster.geometry.triangles import TriangleGeometry
from glraster.types import VALUE_OUTPUTS
from glraster.verify.tolerance import ErrorModel, mesa_noperspective_clip_bug, value_tolerance


@dataclass
class ErrorMaps:
    """Per-pixel maps of one comparison, for reports. Arrays are (H, W), indexed ``[y, x]``
    with row 0 at the bottom, like the rasters.

    coverage : int8, GPU coverage minus reference coverage (-1, 0 or 1)
    persp_error, screen_error, depth_error : float64, |GPU - reference| (max over the
        channels) at the judged pixels, 0 elsewhere; None for an output not compared
    persp_ratio, screen_ratio, depth_ratio : float64, error / per-pixel tolerance (max
        over the channels; 0 where the error is 0) at the judged pixels, 0 elsewhere
    """

    coverage: np.ndarray
    persp_error: np.ndarray | None = None
    persp_ratio: np.ndarray | None = None
    screen_error: np.ndarray | None = None
    screen_ratio: np.ndarray | None = None
    depth_error: np.ndarray | None = None
    depth_ratio: np.ndarray | None = None

    @property
    def outputs(self) -> tuple[str, ...]:
        """The compared value outputs (those with maps), in canonical order."""
        return tuple(n for n in VALUE_OUTPUTS if getattr(self, f"{n}_ratio") is not None)

    def error(self, output: str) -> np.ndarray | None:
        """The error map of ``output`` ("persp", "screen" or "depth")."""
        return getattr(self, f"{_value_output(output)}_error")

    def ratio(self, output: str) -> np.ndarray | None:
        """The error / tolerance map of ``output`` ("persp", "screen" or "depth")."""
        return getattr(self, f"{_value_output(output)}_ratio")


def _value_output(name: str) -> str:
    if name not in VALUE_OUTPUTS:
        raise ValueError(f"output must be one of {VALUE_OUTPUTS}, got {name!r}")
    return name


@dataclass
class ValueStats:
    """|GPU - reference| over pixels both cover with the same triangle (outside ties).

    pixels : number of pixels compared (channels of one pixel count once)
    max, p999, mean : absolute error, largest / 99.9th percentile (nearest rank, so an
        infinite error stays infinite) / mean over all channels
    over_tolerance : pixels where some channel exceeds its per-pixel tolerance
    worst_ratio : largest error / tolerance (<= 1 passes)
    waived : pixels not judged because of a documented driver deviation (ErrorModel)
    """

    pixels: int = 0
    max: float = 0.0
    p999: float = 0.0
    mean: float = 0.0
    over_tolerance: int = 0
    worst_ratio: float = 0.0
    waived: int = 0


@dataclass
class Report:
    """Result of :func:`compare`.

    covered_gpu, covered_ref : pixels covered by each side
    coverage_mismatch : pixels covered by exactly one side, outside the ambiguous pixels
    coverage_mismatch_in_band : the same inside the edge band or a depth tie (accepted)
    tri_id_mismatch : pixels both cover with different triangles, outside the ambiguous pixels
    values : output name -> ValueStats
    model : the ErrorModel the values were judged with
    maps : the per-pixel :class:`ErrorMaps`
    """

    resolution: tuple
    covered_gpu: int
    covered_ref: int
    coverage_mismatch: int
    coverage_mismatch_in_band: int
    tri_id_mismatch: int
    values: dict = field(default_factory=dict)
    model: ErrorModel = ErrorModel()
    maps: ErrorMaps | None = field(default=None, repr=False)

    def ok(self, max_coverage_mismatch: int = 0) -> bool:
        """True when coverage outside the band matches (up to ``max_coverage_mismatch``),
        triangle ids agree and every value is within its per-pixel tolerance."""
        return (
            self.coverage_mismatch <= max_coverage_mismatch
            and self.tri_id_mismatch == 0
            and all(v.over_tolerance == 0 for v in self.values.values())
        )

    def summary(self) -> str:
        """A short table for people."""
        h, w = self.resolution
        lines = [
            f"{h}x{w} (HxW): covered gpu {self.covered_gpu}, reference {self.covered_ref}; "
            f"coverage mismatches {self.coverage_mismatch} "
            f"(+{self.coverage_mismatch_in_band} accepted in edge band / depth ties); "
            f"triangle id mismatches {self.tri_id_mismatch}",
            f"{'output':<8}{'pixels':>9}{'max':>11}{'p99.9':>11}{'mean':>11}"
            f"{'>tol':>7}{'err/tol':>9}{'waived':>8}",
        ]
        for name, v in self.values.items():
            lines.append(
                f"{name:<8}{v.pixels:>9}{v.max:>11.3e}{v.p999:>11.3e}{v.mean:>11.3e}"
                f"{v.over_tolerance:>7}{v.worst_ratio:>9.3f}{v.waived:>8}"
            )
        lines.append("PASS" if self.ok() else "FAIL")
        return "\n".join(lines)


def _row_max(values: np.ndarray) -> np.ndarray:
    """(N, C) -> (N,) max over the C <= 3 channels, column by column (numpy's reduction
    over a short last axis is ~10x slower on large frames)."""
    out = values[:, 0].copy()
    for c in range(1, values.shape[1]):
        np.maximum(out, values[:, c], out=out)
    return out


def waived_pixels(triangles: TriangleGeometry | None, tri_id: np.ndarray,
                  model: ErrorModel) -> np.ndarray:
    """(H, W) bool: pixels where ``model`` does not judge the outputs in
    ``model.waived_outputs`` (the triangles of
    :func:`~glraster.verify.tolerance.mesa_noperspective_clip_bug`).

    triangles : the T triangles' :class:`TriangleGeometry` (``ReferenceRaster.triangles``),
        or None; tri_id : (H, W) int, the triangle at each pixel, -1 where empty."""
    out = np.zeros(tri_id.shape, bool)
    if model.waived_outputs and triangles is not None:
        covered = tri_id >= 0
        out[covered] = mesa_noperspective_clip_bug(triangles)[tri_id[covered]]
    return out


def compare(gpu, ref, model: ErrorModel | None = None) -> Report:
    """Compare a GPU :class:`~glraster.Raster` with a :class:`~glraster.reference.ReferenceRaster`.

    Coverage is compared everywhere; pixels in ``ref.edge_band`` or ``ref.depth_tie`` may
    differ. Values are compared where both sides cover the same triangle, each against its
    per-pixel tolerance from ``model`` (default: the error model for llvmpipe, see
    :mod:`glraster.verify.tolerance`), computed from ``ref.triangles`` and ``ref.tri_id``.
    ``report.maps`` (:class:`ErrorMaps`) holds the per-pixel error and error / tolerance
    ((H, W) max over channels) and the coverage difference for reports.
    """
    if tuple(gpu.resolution) != tuple(ref.resolution):
        raise ValueError(
            f"gpu and ref must have the same resolution, got {gpu.resolution} and {ref.resolution}"
        )
    if ref.tri_id is None:
        raise ValueError("ref must include the 'tri_id' output (the tolerance model needs it)")
    model = model or ErrorModel()
    ambiguous = ref.ambiguous
    differ = gpu.mask != ref.mask
    both = gpu.mask & ref.mask
    same = both.copy()
    tri_mismatch = 0
    if gpu.tri_id is not None:
        same &= gpu.tri_id == ref.tri_id
        tri_mismatch = int((both & ~same & ~ambiguous).sum())
    same &= ~ref.depth_tie
    maps = ErrorMaps(coverage=gpu.mask.astype(np.int8) - ref.mask.astype(np.int8))

    compared = tuple(n for n in VALUE_OUTPUTS
                     if getattr(gpu, n) is not None and getattr(ref, n) is not None)
    tolerances = value_tolerance(ref.triangles, ref.tri_id, compared, model)
    values = {}
    for name in compared:
        g, r = getattr(gpu, name), getattr(ref, name)
        judged = same
        waived = 0
        if name in model.waived_outputs:
            not_judged = waived_pixels(ref.triangles, ref.tri_id, model)
            judged = same & ~not_judged
            waived = int((same & not_judged).sum())
        # Only the judged pixels are touched: big frames stay cheap.
        idx = np.flatnonzero(judged)
        n = judged.size
        g_val = g.reshape(n, -1)[idx].astype(np.float64)
        r_val = r.reshape(n, -1)[idx]
        tol = getattr(tolerances, name).reshape(n, -1)[idx]
        # NaN or Inf from the GPU is an infinite error, never "within tolerance".
        err = np.where(np.isfinite(g_val), np.abs(g_val - r_val), np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(err > 0, err / tol, 0.0)
        err_px, ratio_px = _row_max(err), _row_max(ratio)
        values[name] = ValueStats(
            pixels=len(idx),
            max=float(err.max()) if err.size else 0.0,
            p999=float(np.percentile(err, 99.9, method="higher")) if err.size else 0.0,
            mean=float(err.mean()) if err.size else 0.0,
            over_tolerance=int((ratio_px > 1).sum()),
            worst_ratio=float(ratio_px.max()) if len(idx) else 0.0,
            waived=waived,
        )
        for key, per_pixel in (("error", err_px), ("ratio", ratio_px)):
            full = np.zeros(n)
            full[idx] = per_pixel
            setattr(maps, f"{name}_{key}", full.reshape(judged.shape))
    return Report(
        resolution=tuple(ref.resolution),
        covered_gpu=int(gpu.mask.sum()),
        covered_ref=int(ref.mask.sum()),
        coverage_mismatch=int((differ & ~ambiguous).sum()),
        coverage_mismatch_in_band=int((differ & ambiguous).sum()),
        tri_id_mismatch=tri_mismatch,
        values=values,
        model=model,
        maps=maps,
    )
