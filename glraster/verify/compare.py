"""Comparing a GPU raster with the reference: coverage, triangle ids and values."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from glraster.errors import ArgumentError
from glraster.geometry.triangles import TriangleGeometry
from glraster.types import VALUE_OUTPUTS, first_covered_sample, per_pixel
from glraster.verify.interpolation import PointCheck, check_point
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
        raise ArgumentError("output", f"output must be one of {VALUE_OUTPUTS}, got {name!r}")
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
    samples, interpolation : of the compared rasters; multisampled, coverage and id counts
        are over samples, and the maps (H, W) hold each pixel's worst sample
    point : the :class:`~glraster.verify.interpolation.PointCheck` of the per-pixel
        "center" / "centroid" values (None otherwise); its failures count in ``ok``
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
    samples: int = 1
    interpolation: str = "center"
    point: PointCheck | None = None

    def ok(self, max_coverage_mismatch: int = 0) -> bool:
        """True when coverage outside the band matches (up to ``max_coverage_mismatch``),
        triangle ids agree and every value is within its per-pixel tolerance."""
        return (
            self.coverage_mismatch <= max_coverage_mismatch
            and self.tri_id_mismatch == 0
            and all(v.over_tolerance == 0 for v in self.values.values())
            and (self.point is None or self.point.failures == 0)
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
        if self.point is not None:
            p = self.point
            lines.append(f"{self.interpolation} point: {p.pixels} pixels judged, "
                         f"{p.outside_pixel} outside the pixel, {p.outside_triangle} "
                         f"outside the triangle, {p.persp_inconsistent} persp not "
                         f"perspective-correct there (worst ratio {p.worst_ratio:.3f})")
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

    Multisampled rasters (S > 1, the same S and interpolation on both sides): every sample
    is compared like a pixel, with the tolerances evaluated at its position (ref's
    ``sample_positions``); per-pixel "center" / "centroid" barycentrics are judged by the
    condition GLSL puts on the point they were evaluated at
    (:func:`glraster.verify.interpolation.check_point`), not against one reference point.
    """
    for name, raster, wanted, what in (
            ("gpu", gpu, ("resolution", "mask"), "a raster (glraster.rasterize's result)"),
            ("ref", ref, ("resolution", "mask", "edge_band", "triangles"),
             "a reference raster (glraster.reference.rasterize's result)")):
        if not all(hasattr(raster, field) for field in wanted):
            raise ArgumentError(name, f"{name} must be {what}, got {type(raster).__name__}")
    if tuple(gpu.resolution) != tuple(ref.resolution):
        raise ArgumentError(
            "gpu",
            f"gpu and ref must have the same resolution, got {gpu.resolution} and {ref.resolution}"
        )
    samples = getattr(gpu, "samples", 1), getattr(ref, "samples", 1)
    if samples[0] != samples[1] or gpu.mask.shape != ref.mask.shape:
        raise ArgumentError("gpu", f"gpu and ref must have the same samples per pixel, got "
                                   f"{samples[0]} and {samples[1]}")
    if samples[1] == 1:
        return _compare(gpu, ref, model)
    if gpu.interpolation != ref.interpolation:
        raise ArgumentError("gpu", f"gpu and ref must have the same interpolation, got "
                                   f"{gpu.interpolation!r} and {ref.interpolation!r}")
    return _compare_samples(gpu, ref, model or ErrorModel())


def _sample_view(raster, k: int, values: bool):
    """Sample ``k`` of a multisampled raster as a single-sample one (views, no copies);
    ``values``: keep persp / screen (per-sample with interpolation "sample")."""
    view = copy.copy(raster)
    view.samples, view.sample_positions = 1, None
    view.mask = raster.mask[..., k]
    for name in ("tri_id", "depth", "edge_band", "depth_tie"):
        if getattr(raster, name, None) is not None:
            setattr(view, name, getattr(raster, name)[..., k])
    for name in ("persp", "screen"):
        if getattr(raster, name) is not None:
            setattr(view, name, getattr(raster, name)[..., k, :] if values else None)
    return view


def _compare_samples(gpu, ref, model: ErrorModel) -> Report:
    """:func:`compare` of multisampled rasters: one single-sample comparison per sample,
    merged, plus the point check of per-pixel barycentrics."""
    per_sample = ref.interpolation == "sample"
    # the documented defect (ErrorModel.center_one_over_w): persp off the center waived
    waive_persp = model.center_one_over_w and ref.interpolation != "center" \
        and gpu.persp is not None
    reports = []
    waived = 0
    for k in range(ref.samples):
        g, r = _sample_view(gpu, k, per_sample), _sample_view(ref, k, per_sample)
        if waive_persp and per_sample:
            g.persp = None
            if g.tri_id is not None:
                waived += int((g.mask & r.mask & (g.tri_id == r.tri_id)).sum())
        reports.append(_compare(g, r, model, offset=tuple(ref.sample_positions[k])))
    merged = _merge(reports)
    merged.samples, merged.interpolation = ref.samples, ref.interpolation
    if waive_persp and per_sample:
        merged.values["persp"] = ValueStats(waived=waived)
    if not per_sample and (gpu.persp is not None or gpu.screen is not None) \
            and ref.triangles is not None and gpu.tri_id is not None:
        first = first_covered_sample(gpu.mask)
        gpu_tri = per_pixel(gpu.tri_id, first)
        ref_tri = per_pixel(ref.tri_id, first)
        judged = (gpu_tri == ref_tri) & (gpu_tri >= 0) & ~ref.ambiguous.any(axis=2)
        front = (ref.triangles.clip[:, :, 3] > 0).all(axis=1)
        judged[judged] &= front[gpu_tri[judged]]
        if model.waived_outputs and gpu.screen is not None:
            judged &= ~waived_pixels(ref.triangles, np.where(judged, gpu_tri, -1), model)
        persp = gpu.persp
        if waive_persp and gpu.screen is not None:
            persp = None
            merged.values["persp"] = ValueStats(waived=int(judged.sum()))
        if persp is not None or gpu.screen is not None:
            merged.point = check_point(ref.triangles, gpu_tri, judged, persp, gpu.screen,
                                       ref.interpolation, model)
    return merged


def _merge(reports: list) -> Report:
    """One Report from per-sample ones: counts summed, worst values kept, maps (H, W)
    holding each pixel's worst sample."""
    first = reports[0]
    values = {}
    for name in first.values:
        parts = [r.values[name] for r in reports]
        pixels = sum(v.pixels for v in parts)
        values[name] = ValueStats(
            pixels=pixels, max=max(v.max for v in parts), p999=max(v.p999 for v in parts),
            mean=sum(v.mean * v.pixels for v in parts) / pixels if pixels else 0.0,
            over_tolerance=sum(v.over_tolerance for v in parts),
            worst_ratio=max(v.worst_ratio for v in parts), waived=sum(v.waived for v in parts))
    coverage = np.stack([r.maps.coverage for r in reports])
    strongest = np.abs(coverage).argmax(axis=0)
    maps = ErrorMaps(coverage=np.take_along_axis(coverage, strongest[None], 0)[0])
    for name in first.maps.outputs:
        for key in ("error", "ratio"):
            setattr(maps, f"{name}_{key}",
                    np.max([getattr(r.maps, f"{name}_{key}") for r in reports], axis=0))
    return Report(
        resolution=first.resolution,
        covered_gpu=sum(r.covered_gpu for r in reports),
        covered_ref=sum(r.covered_ref for r in reports),
        coverage_mismatch=sum(r.coverage_mismatch for r in reports),
        coverage_mismatch_in_band=sum(r.coverage_mismatch_in_band for r in reports),
        tri_id_mismatch=sum(r.tri_id_mismatch for r in reports),
        values=values, model=first.model, maps=maps)


def _compare(gpu, ref, model: ErrorModel | None = None, offset=(0.5, 0.5)) -> Report:
    """:func:`compare` of single-sample rasters, values evaluated at ``offset``."""
    if ref.tri_id is None:
        raise ArgumentError(
            "ref", "ref must include the 'tri_id' output (the tolerance model needs it)")
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
    tolerances = value_tolerance(ref.triangles, ref.tri_id, compared, model, offset)
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
