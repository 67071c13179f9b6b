"""Probes of multisampling: each names, in one line, what a driver gets wrong about sample
positions, per-sample and centroid interpolation, per-sample depth, or the readback.

They run with the other probes (:mod:`glraster.conformance.probes`) at every sample count
the driver offers (``Context.sample_counts``), and are "skipped" where it offers none.
Each judges by what GL requires, never by llvmpipe's choices: positions are the driver's
own (GL leaves them to the implementation), a centroid must lie in the pixel and the
triangle (:func:`glraster.verify.interpolation.check_point`).

- ``sample_positions``: the positions used for coverage, measured with edges swept across
  the pixel in 1/64 px steps, against those glGetMultisamplefv reports;
- ``sample_perspective``: per-sample values ("sample") of a perspective and a screen-space
  triangle against the reference at the reported positions;
- ``centroid``: "centroid" values by GLSL's condition on their point;
- ``sample_depth``: depth per sample and the LESS test per sample;
- ``resolve``: every sample read back exactly (ids above 2^16, no blend of fragments).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from glraster import reference as _reference
from glraster.conformance.probes import ProbeResult, _clip, _mentions
from glraster.verify.compare import compare
from glraster.verify.tolerance import ErrorModel

SPEC_POSITIONS = ("GL 4.6 core §14.3.1.1 Sample Positions (GetMultisamplefv with "
                  "SAMPLE_POSITION reports the location of each sample in the pixel, (0.5, "
                  "0.5) its center) and §14.6.6 Polygon Multisample Rasterization (a sample "
                  "is covered when its location is inside the polygon)")
SPEC_SAMPLE = ("GLSL 4.60 §4.5 Interpolation Qualifiers (sample: a separate value for each "
               "covered sample, taken at that sample's location); GL 4.6 core §14.6.1 eq. "
               "14.9 (perspective-correct interpolation at that point)")
SPEC_CENTROID = ("GLSL 4.60 §4.5 Interpolation Qualifiers (centroid: a location in both the "
                 "pixel and the primitive, or one of the pixel's samples inside the "
                 "primitive); GL 4.6 core §14.6.1 eq. 14.9")
SPEC_DEPTH = ("GL 4.6 core §14.6.6 (the depth of each sample from eq. 14.10 at the sample "
              "location) and §17.3.6 (the depth test per sample)")
SPEC_RESOLVE = ("GL 4.6 core §11.1.3.5 Texel Fetches (texelFetch of a multisample texture "
                "returns the given sample) and §9.2.4 (each sample of a multisample image "
                "holds its own value)")

FULL = np.array([[-1, -1, 0, 1], [3, -1, 0, 1], [-1, 3, 0, 1]], np.float32)
STEPS = 64  # edge positions per pixel when measuring a sample position (1/64 px)


def _counts(ctx) -> list:
    return [s for s in ctx.sample_counts if s > 1]


def _skipped(p: ProbeResult, ctx) -> ProbeResult:
    p.status = "skipped"
    p.detail = f"{ctx.renderer} offers no multisampling (GL_MAX_SAMPLES {ctx.max_samples})"
    return p


def _per_count(p: ProbeResult, ctx, check, explains, known_note: str = "") -> ProbeResult:
    """Run ``check(samples, details, problems, known)`` (lists it appends to) at every
    sample count the driver offers (skipped where it offers none) and give ``p`` its
    verdict: "fail" on any problem, "known" when only known defects were found, else
    "pass"; ``explains(scene, failure)`` then tells which scene failures the probe
    accounts for."""
    counts = _counts(ctx)
    if not counts:
        return _skipped(p, ctx)
    found = _Found([], [], [])
    for samples in counts:
        check(samples, *found)
    p.detail = "; ".join(found.details)
    if found.problems:
        p.status, p.diagnosis = "fail", "; ".join(found.problems + found.known)
    elif found.known:
        p.status, p.diagnosis = "known", "; ".join(found.known) + known_note
    if p.failed:
        p._explains = lambda self, scene, f: explains(scene, f)
    return p


class _Found(NamedTuple):
    """What a probe's check found at each count: lines of detail, problems, and known
    driver defects (waived, named in the diagnosis)."""

    details: list
    problems: list
    known: list


def reported_positions(render, samples: int) -> np.ndarray:
    """(S, 2) the positions the driver reports (Raster.sample_positions)."""
    return render(FULL, np.array([[0, 1, 2]], np.int32), (1, 1), ("tri_id",),
                  samples=samples).sample_positions


def measured_positions(render, samples: int) -> np.ndarray:
    """(S, 2) the positions the driver uses for coverage: in pixel column c of a 64-wide
    strip a rectangle starts at x = c + (c + 1/2) / 64 and ends at the pixel's right
    border, so sample s is covered for the first round(64 x_s) columns; the same with
    rows for y. Accurate to 1/128 px."""
    out = np.zeros((samples, 2))
    for axis in (0, 1):
        res = (4, STEPS) if axis == 0 else (STEPS, 4)
        quads = []
        for c in range(STEPS):
            start = c + (c + 0.5) / STEPS
            lo, hi = (start, -2.0), (c + 1.0, 6.0)
            if axis == 1:
                lo, hi = (-2.0, start), (6.0, c + 1.0)
            quads += [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]
        pos = _clip(quads, res)
        tri = np.array([[4 * k, 4 * k + 1, 4 * k + 2] for k in range(STEPS)]
                       + [[4 * k, 4 * k + 2, 4 * k + 3] for k in range(STEPS)], np.int32)
        mask = render(pos, tri, res, ("tri_id",), samples=samples).mask   # (H, W, S)
        line = mask[1, :, :] if axis == 0 else mask[:, 1, :]              # (64, S)
        out[:, axis] = line.sum(axis=0) / STEPS
    return out


def probe_sample_positions(render, ctx) -> ProbeResult:
    p = ProbeResult("sample_positions", SPEC_POSITIONS,
                    "coverage is sampled at the positions GL_SAMPLE_POSITION reports "
                    "(measured to 1/128 px), each inside the pixel")

    def check(samples, details, problems, _known):
        reported = reported_positions(render, samples)
        measured = measured_positions(render, samples)
        details.append(f"{samples}x reported {reported.tolist()}, measured "
                       f"{np.round(measured, 4).tolist()}")
        off = np.abs(measured - reported).max(axis=1) > 1.0 / (2 * STEPS) + 1e-9
        if not ((reported >= 0) & (reported <= 1)).all():
            problems.append(f"{samples}x: reported positions outside the pixel: "
                            f"{reported.tolist()}")
        elif off.any():
            flipped = reported * [1, -1] + [0, 1]
            if np.abs(measured - flipped).max() <= 1.0 / (2 * STEPS) + 1e-9:
                problems.append(f"{samples}x: the reported positions have y flipped (y down): "
                                f"sample k is used at (x_k, 1 - y_k)")
            else:
                k = int(np.flatnonzero(off)[0])
                problems.append(f"{samples}x: sample {k} is reported at "
                                f"{reported[k].tolist()} but used at "
                                f"{np.round(measured[k], 4).tolist()} ({int(off.sum())} of "
                                f"{samples} samples differ)")

    return _per_count(p, ctx, check, lambda scene, f: scene.samples > 1)


def _perspective_scene(res=(16, 16)):
    """One perspective triangle (clip w 1, 3, 9) over most of the viewport and one
    screen-space triangle (w = 1) beside it."""
    h, w = res
    persp = _clip([(0.3, 0.4), (w - 0.2, 1.1), (1.2, h - 0.3)], res, w=[1.0, 3.0, 9.0],
                  z=[-0.5, 0.2, 0.7])
    flat = _clip([(w - 0.3, 1.6), (w - 0.1, h - 0.2), (1.9, h - 0.1)], res,
                 z=[0.1, 0.1, 0.1])
    return np.concatenate([persp, flat]), np.array([[0, 1, 2], [3, 4, 5]], np.int32), res


def _center_one_over_w(ref, positions) -> np.ndarray:
    """(H, W, S, 3) what a driver that divides the b_i / w_i interpolated at each sample
    by the 1 / w interpolated at the pixel center produces (ErrorModel.center_one_over_w)."""
    ts = ref.triangles
    h, w = ref.resolution
    out = np.zeros(ref.mask.shape + (3,))
    ys, xs, ks = np.nonzero(ref.mask)
    t = ref.tri_id[ys, xs, ks]
    a = ts.adj[t]

    def s_at(px, py):
        return (a[..., 0] * px[:, None] + a[..., 1] * py[:, None] + a[..., 2]) \
            / ts.det[t][:, None]
    at_sample = s_at(xs + positions[ks, 0], ys + positions[ks, 1])
    at_center = s_at(xs + 0.5, ys + 0.5)
    out[ys, xs, ks] = at_sample / at_center.sum(axis=1)[:, None]
    return out


def _unwaived_model(ctx) -> ErrorModel:
    """The driver's error model with no output waived: a probe measures the defects that
    a check waives."""
    model = ErrorModel.for_context(ctx)
    return ErrorModel(model.ulp_factor, model.position_error_px, waived_outputs=())


def _render_perspective(render, samples: int, interpolation: str):
    """The perspective probe scene at ``samples`` with ``interpolation``: (GPU raster,
    reference raster at the sample positions the GPU reports)."""
    pos, tri, res = _perspective_scene()
    outputs = ("persp", "screen", "tri_id")
    gpu = render(pos, tri, res, outputs, samples=samples, interpolation=interpolation)
    ref = _reference.rasterize(pos, tri, res, outputs=outputs, samples=samples,
                               sample_positions=gpu.sample_positions,
                               interpolation=interpolation)
    return gpu, ref


def probe_sample_perspective(render, ctx) -> ProbeResult:
    p = ProbeResult("sample_perspective", SPEC_SAMPLE,
                    "per-sample (interpolation='sample') persp and screen equal the "
                    "reference at each reported sample position, on a perspective and a "
                    "screen-space triangle")
    model = _unwaived_model(ctx)

    def check(samples, details, problems, known):
        gpu, ref = _render_perspective(render, samples, "sample")
        rep = compare(gpu, ref, model=model)
        sp, sc = rep.values["persp"], rep.values["screen"]
        details.append(f"{samples}x: persp max error {sp.max:.3g} ({sp.over_tolerance} "
                       f"samples over tolerance), screen {sc.max:.3g} ({sc.over_tolerance})")
        if rep.tri_id_mismatch or rep.coverage_mismatch:
            problems.append(f"{samples}x: per-sample coverage differs from the reference "
                            f"({rep.coverage_mismatch} samples, {rep.tri_id_mismatch} ids)")
        elif sc.over_tolerance:
            problems.append(f"{samples}x: window-space values are not taken at the sample "
                            f"positions ({sc.over_tolerance} samples, max error {sc.max:.3g})")
        elif sp.over_tolerance:
            same = gpu.mask & ref.mask & (gpu.tri_id == ref.tri_id)
            defect = _center_one_over_w(ref, gpu.sample_positions)
            err = np.abs(gpu.persp[same] - defect[same]).max()
            if err <= 1e-5:
                known.append(
                    f"{samples}x: perspective-correct values at a sample divide the b/w "
                    f"interpolated there by the 1/w of the pixel center (persp off by up "
                    f"to {sp.max:.3g}; the model of that matches to {err:.1g})")
            else:
                problems.append(f"{samples}x: per-sample persp is not perspective-correct at "
                                f"the sample ({sp.over_tolerance} samples, max error "
                                f"{sp.max:.3g})")

    def explains(scene, f):
        return (scene.samples > 1 and scene.interpolation != "center"
                and _mentions(f, "persp", "point"))

    return _per_count(p, ctx, check, explains,
                      " (docs/drivers.md; ErrorModel.center_one_over_w)")


def probe_centroid(render, ctx) -> ProbeResult:
    p = ProbeResult("centroid", SPEC_CENTROID,
                    "centroid values are those of a point inside both the pixel and the "
                    "triangle, persp perspective-correct at that point")
    model = _unwaived_model(ctx)

    def check(samples, details, problems, known):
        gpu, ref = _render_perspective(render, samples, "centroid")
        point = compare(gpu, ref, model=model).point
        partial = gpu.mask.any(axis=2) & ~gpu.mask.all(axis=2)
        details.append(f"{samples}x: {point.pixels} pixels judged ({int(partial.sum())} "
                       f"partly covered): {point.outside_pixel} outside the pixel, "
                       f"{point.outside_triangle} outside the triangle, "
                       f"{point.persp_inconsistent} persp not perspective-correct there")
        if point.outside_pixel or point.outside_triangle:
            problems.append(f"{samples}x: centroid values are taken outside the "
                            + ("pixel" if point.outside_pixel else "triangle")
                            + f" ({point.outside_pixel + point.outside_triangle} pixels"
                            + (", e.g. at the pixel center of partly covered pixels)"
                               if point.outside_triangle else ")"))
        elif point.persp_inconsistent:
            # the point is fine: is persp the sample-defect's b/w there over center 1/w?
            ys, xs = np.nonzero(gpu.mask.any(axis=2))
            t = np.array([gpu.tri_id[y, x][gpu.mask[y, x]][0] for y, x in zip(ys, xs)])
            ts = ref.triangles
            w = ts.clip[t, :, 3]
            s_point = gpu.screen[ys, xs].astype(np.float64) / w
            a = ts.adj[t]
            s_center = (a[..., 0] * (xs + 0.5)[:, None] + a[..., 1] * (ys + 0.5)[:, None]
                        + a[..., 2]) / ts.det[t][:, None]
            err = np.abs(gpu.persp[ys, xs] - s_point / s_center.sum(axis=1)[:, None]).max()
            if err <= 1e-5:
                known.append(f"{samples}x: centroid persp divides the b/w interpolated at "
                             f"the centroid by the 1/w of the pixel center "
                             f"({point.persp_inconsistent} pixels)")
            else:
                problems.append(f"{samples}x: centroid persp is not perspective-correct at "
                                f"its own point ({point.persp_inconsistent} pixels)")

    def explains(scene, f):
        return scene.interpolation == "centroid" and _mentions(f, "point", "persp")

    return _per_count(p, ctx, check, explains, " (the defect of sample_perspective)")


def probe_sample_depth(render, ctx) -> ProbeResult:
    p = ProbeResult("sample_depth", SPEC_DEPTH,
                    "depth is evaluated at each sample and tested per sample: a sloped "
                    "plane within the error model at every sample, two interpenetrating "
                    "triangles owning the samples the reference gives them")
    model = ErrorModel.for_context(ctx)
    res = (16, 16)

    def check(samples, details, problems, _known):
        slope = _clip([(0.5, 0.5), (15.5, 0.5), (0.5, 15.5)], res, z=[-0.9, 0.9, 0.0])
        gpu = render(slope, np.array([[0, 1, 2]], np.int32), res, ("depth", "tri_id"),
                     samples=samples)
        ref = _reference.rasterize(slope, [[0, 1, 2]], res, outputs=("depth", "tri_id"),
                                   samples=samples, sample_positions=gpu.sample_positions)
        rep = compare(gpu, ref, model=model)
        d = rep.values["depth"]
        both = gpu.mask & ref.mask
        spread = np.ptp(np.where(both, gpu.depth, np.nan), axis=2)
        flat = bool(np.nanmax(spread) == 0) if both.any() else False
        details.append(f"{samples}x: depth max error {d.max:.3g} ({d.over_tolerance} samples "
                       f"over tolerance)")
        if flat:
            problems.append(f"{samples}x: every sample of a pixel holds the same depth (the "
                            f"pixel center's, not each sample's)")
        elif d.over_tolerance:
            problems.append(f"{samples}x: per-sample depth is off by up to {d.max:.3g} "
                            f"({d.over_tolerance} samples over tolerance)")
        cross = np.concatenate([
            _clip([(0.2, 0.3), (15.8, 0.6), (8.1, 15.7)], res, z=[-0.8, 0.8, 0.0]),
            _clip([(0.4, 15.6), (15.7, 15.2), (7.9, 0.2)], res, z=[-0.7, 0.7, 0.05])])
        tri = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
        gpu = render(cross, tri, res, ("tri_id",), samples=samples)
        ref = _reference.rasterize(cross, tri, res, outputs=("tri_id", "depth"),
                                   samples=samples, sample_positions=gpu.sample_positions)
        wrong = int(((gpu.tri_id != ref.tri_id) & ~ref.ambiguous).sum())
        details[-1] += f"; interpenetrating: {wrong} samples with the wrong owner"
        if wrong:
            problems.append(f"{samples}x: the depth test per sample keeps the wrong triangle "
                            f"on {wrong} samples of two interpenetrating triangles")

    return _per_count(p, ctx, check,
                      lambda scene, f: scene.samples > 1 and _mentions(f, "depth", "id"))


def probe_resolve(render, ctx) -> ProbeResult:
    p = ProbeResult("resolve", SPEC_RESOLVE,
                    "every sample reads back its own fragment exactly: triangle ids above "
                    "2^16 unchanged, pixels on a shared edge hold one id per sample, never a "
                    "blend, and the barycentrics of each sample sum to 1")
    res = (8, 8)
    offset = (1 << 16) + 3

    def check(samples, details, problems, _known):
        quad = _clip([(0.2, 0.3), (7.9, 0.1), (0.3, 7.8), (7.7, 7.9)], res)
        pos = np.concatenate([quad, _clip([(0.5, 0.5)], res)])
        tri = np.full((offset + 2, 3), 4, np.int32)      # zero-area triangles, numbered
        tri[offset], tri[offset + 1] = (0, 1, 2), (1, 3, 2)
        gpu = render(pos, tri, res, ("screen", "tri_id"), samples=samples,
                     interpolation="sample")
        ids = set(np.unique(gpu.tri_id).tolist())
        mixed = int(((gpu.tri_id == offset).any(axis=2)
                     & (gpu.tri_id == offset + 1).any(axis=2)).sum())
        sums = gpu.screen.sum(axis=-1)[gpu.mask]
        details.append(f"{samples}x: ids {sorted(ids)}, {mixed} pixels shared by both, "
                       f"barycentric sums in [{sums.min():.7f}, {sums.max():.7f}]")
        if not ids <= {-1, offset, offset + 1}:
            problems.append(f"{samples}x: per-sample ids are not read back exactly (found "
                            f"{sorted(ids - {-1, offset, offset + 1})[:4]})")
        elif not mixed:
            problems.append(f"{samples}x: no pixel holds both triangles of a shared edge: "
                            f"the samples of a pixel are not read back one by one")
        elif np.abs(sums - 1).max() > 1e-5:
            problems.append(f"{samples}x: per-sample barycentrics do not sum to 1 (down to "
                            f"{sums.min():.3g}): samples of different fragments are mixed")

    return _per_count(p, ctx, check, lambda scene, f: scene.samples > 1)


PROBES = (("sample_positions", probe_sample_positions),
          ("sample_perspective", probe_sample_perspective), ("centroid", probe_centroid),
          ("sample_depth", probe_sample_depth), ("resolve", probe_resolve))
