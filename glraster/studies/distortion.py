"""Affine (screen-space) against perspective-correct texture mapping.

Two things live here:

* :func:`segment_example`: the worked example of docs/distortion.md, exactly, in rational arithmetic.  A
  camera at the origin looks along the view axis at a segment from V0 = (x, depth) =
  (-4, 2) to V1 = (2, 5); the image plane is at distance 1.  The ray through screen
  position x' = 0 hits the segment at P = (0, 4).  On the screen, x' = 0 lies 5/6 of the
  way from V0' = -2 to V1' = 2/5, so interpolating depth *affinely* in screen space gives
  (1/6) 2 + (5/6) 5 = 9/2, while the true depth is 4; interpolating 1/depth affinely and
  inverting (GL 4.6 eq. 14.9; Heckbert & Moreton 1991) gives 1 / ((1/6)/2 + (5/6)/5) = 4.
  :func:`segment_example_gpu` reproduces both numbers on the GPU with ``noperspective``
  and ``smooth`` barycentrics.

* :func:`render_comparison` / :func:`write_comparison`: a tilted checkerboard plane and a
  cube with per-face checkerboards, textured with uv interpolated affinely (``screen``
  barycentrics, the PlayStation-1 look) and perspective-correctly (``persp``), plus the
  per-pixel uv error, written as PNGs, a labeled side-by-side figure and an EXR.

All images leave this module **upright** (file row 0 = top = array row H - 1).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from glraster import validate
from glraster.io.atomic import staged_folder, write_image, write_text
from glraster.geometry import camera as cam
from glraster.interpolate import interpolate

__all__ = ["SegmentExample", "segment_example", "segment_example_gpu", "DistortionScene",
           "builtin_scenes", "DistortionResult", "checker", "render_scene_comparison",
           "render_comparison", "write_comparison"]

ORIENTATION = "upright: file row 0 is the top row (glraster array row H-1)"


# --------------------------------------------------------------------------- worked example


@dataclass(frozen=True)
class SegmentExample:
    """Exact numbers of the 1D worked example (all :class:`fractions.Fraction`).

    v0, v1          : (x, depth) of the segment ends in camera space
    s0, s1          : their screen positions x / depth (image plane at distance 1)
    screen_x        : the screen position looked at
    t               : screen-space (affine) weight of v1 at ``screen_x``
    affine_depth    : (1 - t) d0 + t d1, what screen-space interpolation gives
    correct_depth   : 1 / ((1 - t)/d0 + t/d1), perspective-correct interpolation
    true_point      : (x, depth) where the ray through ``screen_x`` meets the segment
    true_fraction   : that point's fraction along the segment, from v0
    affine_fraction : the fraction screen-space interpolation claims (= t)
    """

    v0: tuple
    v1: tuple
    s0: Fraction
    s1: Fraction
    screen_x: Fraction
    t: Fraction
    affine_depth: Fraction
    correct_depth: Fraction
    true_point: tuple
    true_fraction: Fraction
    affine_fraction: Fraction

    def lines(self) -> list[str]:
        f = lambda q: f"{q}" if q.denominator == 1 else f"{q} = {float(q):.6g}"  # noqa: E731
        return [
            f"segment V0 = (x {self.v0[0]}, depth {self.v0[1]}) to V1 = (x {self.v1[0]}, "
            f"depth {self.v1[1]}); image plane at distance 1",
            f"screen: V0' = {f(self.s0)}, V1' = {f(self.s1)}; looking at x' = {self.screen_x}, "
            f"t = {f(self.t)} of the way from V0' to V1'",
            f"affine (screen-space) depth  (1-t) d0 + t d1        = {f(self.affine_depth)}",
            f"perspective-correct depth   1/((1-t)/d0 + t/d1)    = {f(self.correct_depth)}",
            f"true point on the ray: (x {self.true_point[0]}, depth {self.true_point[1]}), "
            f"{f(self.true_fraction)} along the segment (affine claims {f(self.affine_fraction)})",
        ]


def segment_example(v0=(-4, 2), v1=(2, 5), screen_x=0) -> SegmentExample:
    """The worked example for segment ``v0``-``v1`` (x, depth), depths > 0, seen at
    ``screen_x``; defaults are the worked example's numbers (affine 9/2 against true 4)."""
    try:
        x0, d0 = (Fraction(c) for c in v0)
        x1, d1 = (Fraction(c) for c in v1)
    except (TypeError, ValueError):
        raise ValueError(f"v0 and v1 must be (x, depth) pairs of rationals, "
                         f"got {v0!r}, {v1!r}") from None
    try:
        sx = Fraction(screen_x)
    except (TypeError, ValueError):
        raise ValueError(f"screen_x must be a rational number, got {screen_x!r}") from None
    if d0 <= 0 or d1 <= 0:
        raise ValueError(f"v0 and v1 must have depth > 0, got {d0} and {d1}")
    s0, s1 = x0 / d0, x1 / d1
    if s0 == s1:
        raise ValueError("v0 and v1 project to the same screen point")
    t = (sx - s0) / (s1 - s0)
    if not 0 <= t <= 1:
        raise ValueError(f"screen_x must lie between the projections {s0} and {s1}, got {sx}")
    affine = (1 - t) * d0 + t * d1
    correct = 1 / ((1 - t) / d0 + t / d1)
    # The ray x = sx * depth meets x0 + u (x1 - x0) = sx (d0 + u (d1 - d0)).
    u = (sx * d0 - x0) / ((x1 - x0) - sx * (d1 - d0))
    point = (x0 + u * (x1 - x0), d0 + u * (d1 - d0))
    return SegmentExample((x0, d0), (x1, d1), s0, s1, sx, t, affine, correct, point, u, t)


def segment_example_gpu(ctx=None, size: int = 33) -> dict:
    """The worked example on the GPU.

    The segment becomes a triangle A = (-4, -4, depth 2), C = (-4, 4, depth 2),
    B = (2, 0, depth 5) in eye space, so depth depends on x only and every pixel on the
    screen column x' = 0 sees true depth 4.  A projection with x_c = 0.4 x_e,
    y_c = 0.4 y_e, w_c = depth puts x' = 0 at NDC 0, the center of pixel column
    ``size // 2`` (``size`` odd).  Per-vertex depth is interpolated there with
    ``screen`` (affine) and ``persp`` barycentrics.

    Returns:
        {"pixel": (x, y), "screen_weight_B": float, "affine_depth": float,
         "correct_depth": float} read at the center pixel.
    """
    from glraster.gpu.rasterize import rasterize

    if size < 9 or size % 2 != 1:
        raise ValueError(f"size must be an odd integer >= 9, got {size}")
    depth = np.array([2.0, 2.0, 5.0])
    eye = np.array([[-4.0, -4.0, -2.0], [-4.0, 4.0, -2.0], [2.0, 0.0, -5.0]])
    near, far = 1.0, 10.0
    proj = np.array([[0.4, 0, 0, 0], [0, 0.4, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                     [0, 0, -1, 0]])
    pos = cam.project(eye, proj=proj)
    tri = np.array([[0, 1, 2]])
    r = rasterize(pos, tri, (size, size), ctx=ctx, outputs=("persp", "screen", "tri_id"))
    c = size // 2
    if r.tri_id[c, c] != 0:
        raise RuntimeError("the center pixel of the worked-example triangle is not covered")
    return {
        "pixel": (c, c),
        "screen_weight_B": float(r.screen[c, c, 2]),
        "affine_depth": float(interpolate(depth, r, tri, space="screen")[c, c]),
        "correct_depth": float(interpolate(depth, r, tri, space="persp")[c, c]),
    }


# --------------------------------------------------------------------------- scenes


@dataclass(frozen=True)
class DistortionScene:
    """A textured test scene.

    vertices : (V, 3) float64 world positions;  faces : (T, 3) int64
    uv       : (V, 2) float64 texture coordinates;  shade : (T,) float64 per-face brightness
    checks   : checker squares per unit of uv
    view, proj : (4, 4) OpenGL matrices
    """

    name: str
    title: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    shade: np.ndarray
    checks: int
    view: np.ndarray
    proj: np.ndarray


def _plane(aspect: float) -> DistortionScene:
    # A 2x2 square on y = 0 seen from just above its near edge: depth grows ~6x from the
    # near edge to the far edge.  Two triangles only, so the affine seam is long.
    v = np.array([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 0.0, -1.0]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    view = cam.look_at([0.0, 0.5, 1.3], [0.0, -0.12, -0.3], [0.0, 1.0, 0.0])
    proj = cam.perspective(70.0, aspect, 0.1, 10.0)
    return DistortionScene("plane", "tilted plane (2 triangles)", v, f, uv, np.ones(2), 8, view,
                           proj)


def _cube(aspect: float) -> DistortionScene:
    # 6 faces x 4 corners with their own uv square; seen up close with a wide lens.
    verts, uvs, faces, shade = [], [], [], []
    light = np.array([0.35, 0.6, 0.72])
    light /= np.linalg.norm(light)
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            a = np.roll([0.0, 1.0, 0.0] if axis != 1 else [0.0, 0.0, 1.0], 0)
            u_dir = np.cross(a, n)
            v_dir = np.cross(n, u_dir)
            base = len(verts)
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                verts.append(n + (2 * du - 1) * u_dir + (2 * dv - 1) * v_dir)
                uvs.append((du, dv))
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            s = 0.55 + 0.45 * max(float(n @ light), 0.0)
            shade += [s, s]
    view = cam.look_at([1.45, 1.35, 1.85], [0.0, -0.05, 0.0], [0.0, 1.0, 0.0])
    proj = cam.perspective(72.0, aspect, 0.1, 10.0)
    return DistortionScene("cube", "cube, 2 triangles per face", np.array(verts) * 0.9,
                           np.array(faces), np.array(uvs, float), np.array(shade), 4, view, proj)


def builtin_scenes(resolution=(360, 480)) -> list[DistortionScene]:
    """The tilted plane and the cube, framed for ``resolution`` (H, W)."""
    H, W = resolution
    return [_plane(W / H), _cube(W / H)]


# --------------------------------------------------------------------------- rendering

BACKGROUND = np.array([0.16, 0.17, 0.19])
DARK = np.array([0.10, 0.32, 0.42])
LIGHT = np.array([0.95, 0.86, 0.62])


def checker(uv: np.ndarray, checks: int) -> np.ndarray:
    """(..., 2) uv -> (...,) float64 in {0, 1}: the checkerboard with ``checks`` squares
    per unit of uv, evaluated exactly at each uv (no filtering)."""
    cells = np.floor(uv * checks).astype(np.int64)
    return ((cells[..., 0] + cells[..., 1]) & 1).astype(np.float64)


@dataclass
class DistortionResult:
    """Images of one scene, arrays with row 0 at the bottom, at the output resolution.

    affine, correct : (H, W, 3) float32 RGB in [0, 1]
    uv_affine, uv_correct : (H, W, 2) float32 uv per pixel (supersample average)
    uv_error : (H, W) float32 |uv_affine - uv_correct| in checker squares (0 where empty)
    coverage : (H, W) float32 covered fraction of each pixel's samples
    stats : {"max_uv_error", "mean_uv_error", "pixels_changed"} (checker squares; fraction
            of covered pixels whose color differs)
    """

    scene: DistortionScene
    affine: np.ndarray
    correct: np.ndarray
    uv_affine: np.ndarray
    uv_correct: np.ndarray
    uv_error: np.ndarray
    coverage: np.ndarray
    stats: dict = field(default_factory=dict)


def _box(a: np.ndarray, k: int) -> np.ndarray:
    """Average k x k blocks of (kH, kW, ...) -> (H, W, ...)."""
    H, W = a.shape[0] // k, a.shape[1] // k
    return a.reshape(H, k, W, k, *a.shape[2:]).mean(axis=(1, 3))


def render_scene_comparison(scene: DistortionScene, resolution=(360, 480),
                            supersample: int = 3, ctx=None) -> DistortionResult:
    """Render ``scene`` with affine and perspective-correct uv.

    Each output pixel averages ``supersample`` x ``supersample`` samples (the GPU renders
    at that multiple of ``resolution``), so the far checkers do not alias.
    """
    from glraster.gpu.rasterize import rasterize

    H, W = validate.positive_int("resolution[0]", resolution[0]), validate.positive_int("resolution[1]", resolution[1])
    k = validate.positive_int("supersample", supersample)
    pos = cam.project(scene.vertices, None, scene.view, scene.proj)
    if not np.all(np.abs(pos[:, 2]) < pos[:, 3]):
        # A near/far-clipped triangle has no meaningful window-space (affine) barycentrics:
        # its vertices behind the eye have no window position.
        raise ValueError(f"scene {scene.name!r} must lie between the near and far planes; "
                         "affine interpolation is undefined for clipped triangles")
    r = rasterize(pos, scene.faces, (H * k, W * k), ctx=ctx,
                  outputs=("persp", "screen", "tri_id"))
    shade = np.where(r.mask, scene.shade[np.maximum(r.tri_id, 0)], 0.0)[..., None]
    images, uvs = {}, {}
    for name, space in (("affine", "screen"), ("correct", "persp")):
        uv = interpolate(scene.uv, r, scene.faces, space=space).astype(np.float64)
        c = checker(uv, scene.checks)[..., None]
        rgb = (DARK + c * (LIGHT - DARK)) * shade
        rgb = np.where(r.mask[..., None], rgb, BACKGROUND)
        images[name] = _box(rgb, k).astype(np.float32)
        uvs[name] = uv
    err = np.linalg.norm(uvs["affine"] - uvs["correct"], axis=-1) * scene.checks
    cover = r.mask.astype(np.float64)
    with np.errstate(invalid="ignore"):
        uv_a = _box(uvs["affine"], k) / np.maximum(_box(cover, k), 1e-12)[..., None]
        uv_c = _box(uvs["correct"], k) / np.maximum(_box(cover, k), 1e-12)[..., None]
    colour_a = checker(uvs["affine"], scene.checks)
    colour_c = checker(uvs["correct"], scene.checks)
    stats = {
        "max_uv_error": float(err[r.mask].max()),
        "mean_uv_error": float(err[r.mask].mean()),
        "pixels_changed": float((colour_a != colour_c)[r.mask].mean()),
    }
    return DistortionResult(scene, images["affine"], images["correct"], uv_a.astype(np.float32),
                       uv_c.astype(np.float32), _box(err, k).astype(np.float32),
                       _box(cover, k).astype(np.float32), stats)


def render_comparison(resolution=(360, 480), supersample: int = 3,
                      ctx=None) -> list[DistortionResult]:
    """:func:`render_scene_comparison` for every :func:`builtin_scenes` scene."""
    return [render_scene_comparison(s, resolution, supersample, ctx)
            for s in builtin_scenes(resolution)]


# --------------------------------------------------------------------------- writing


def _upright(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a[::-1])


def _png_meta(what: str) -> dict:
    from glraster._version import __version__

    return {"Title": f"glraster distortion: {what}", "Description": ORIENTATION,
            "Software": f"glraster {__version__}"}


def _write_exr(path: str, results: list[DistortionResult]) -> None:
    import OpenImageIO as oiio

    H, W = results[0].affine.shape[:2]
    names, planes = [], []
    for res in results:
        n = res.scene.name
        for label, img in (("affine", res.affine), ("correct", res.correct)):
            names += [f"{n}.{label}.R", f"{n}.{label}.G", f"{n}.{label}.B"]
            planes += [img[..., 0], img[..., 1], img[..., 2]]
        names += [f"{n}.uv_affine.u", f"{n}.uv_affine.v", f"{n}.uv_correct.u",
                  f"{n}.uv_correct.v", f"{n}.uv_error.Y"]
        planes += [res.uv_affine[..., 0], res.uv_affine[..., 1], res.uv_correct[..., 0],
                   res.uv_correct[..., 1], res.uv_error]
    data = _upright(np.stack(planes, axis=-1).astype(np.float32))
    spec = oiio.ImageSpec(W, H, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    spec.attribute("glraster:orientation", ORIENTATION)
    spec.attribute("glraster:producer", "glraster.studies.distortion")
    spec.attribute("glraster:uv_error_unit", "checker squares")
    write_image(path, spec, data, ".exr")


def write_comparison(out_dir="out/distortion", resolution=(360, 480), supersample: int = 3,
                     ctx=None) -> dict:
    """Render the built-in scenes and write, under ``out_dir``:

    - ``<scene>_affine.png``, ``<scene>_correct.png``: the textured images;
    - ``<scene>_diff.png``: heatmap of the affine uv error (checker squares) with a color bar;
    - ``distortion_figure.png``: all of them side by side, labeled;
    - ``distortion.exr``: every image and uv channel (float32, upright);
    - ``segment_example.txt`` and ``summary.json``: the worked example and the numbers.

    Returns:
        {"files": [paths], "scenes": {name: stats}, "segment_example": {...}}.
    """
    results = render_comparison(resolution, supersample, ctx)
    with staged_folder(out_dir) as stage:   # the whole set replaces the last run's, or none
        summary, text = _write_files(results, stage, resolution, supersample, ctx)
    summary["files"] = [os.path.join(out_dir, name) for name in summary.pop("names")]
    summary["text"] = text
    return summary


def _write_files(results, stage, resolution, supersample: int, ctx):
    """Write :func:`write_comparison`'s files into the folder ``stage``: (the summary, with
    ``names`` the files' names in order; the worked example's lines)."""
    from glraster.io import figures
    from glraster.io.png import write_png

    files = []

    for res in results:
        n = res.scene.name
        for label, img in (("affine", res.affine), ("correct", res.correct)):
            p = os.path.join(stage, f"{n}_{label}.png")
            write_png(p, img, metadata=_png_meta(f"{n} {label}"))  # row 0 at the bottom
            files.append(p)
        p = os.path.join(stage, f"{n}_diff.png")
        meta = _png_meta(f"{n} uv error heatmap")
        with figures.figure(p, figsize=(6.4, 4.8), dpi=100, title=meta["Title"],
                            description=meta["Description"]) as fig:
            ax = fig.subplots()
            im = ax.imshow(_upright(res.uv_error), cmap="magma", vmin=0.0)
            ax.set_title(f"{res.scene.title}: |uv affine - uv correct|")
            ax.set_axis_off()
            fig.colorbar(im, ax=ax, shrink=0.85, label="uv error (checker squares)")
        files.append(p)

    p = os.path.join(stage, "distortion_figure.png")
    meta = _png_meta("side-by-side figure")
    with figures.figure(p, figsize=(16, 4.6 * len(results)), dpi=100, title=meta["Title"],
                        description=meta["Description"]) as fig:
        axes = fig.subplots(len(results), 3, squeeze=False)
        for row, res in zip(axes, results):
            st = res.stats
            row[0].imshow(np.clip(_upright(res.affine), 0, 1))
            row[0].set_title(f"{res.scene.title}\naffine uv (noperspective / screen barycentrics)")
            row[1].imshow(np.clip(_upright(res.correct), 0, 1))
            row[1].set_title(f"{res.scene.title}\nperspective-correct uv (smooth / persp "
                             "barycentrics)")
            im = row[2].imshow(_upright(res.uv_error), cmap="magma", vmin=0.0)
            row[2].set_title(f"|uv affine - uv correct|: max {st['max_uv_error']:.2f}, "
                             f"mean {st['mean_uv_error']:.2f} squares\n"
                             f"{100 * st['pixels_changed']:.0f}% of covered pixels change color")
            fig.colorbar(im, ax=row[2], shrink=0.9, label="uv error (checker squares)")
            for ax in row:
                ax.set_axis_off()
        fig.suptitle("Affine distortion against perspective-correct interpolation (glraster, "
                     f"{resolution[0]}x{resolution[1]} (HxW), {supersample}x{supersample} "
                     "supersampled)", fontsize=14)
    files.append(p)

    p = os.path.join(stage, "distortion.exr")
    _write_exr(p, results)
    files.append(p)

    ex = segment_example()
    gpu = segment_example_gpu(ctx)
    text = ex.lines() + [
        f"GPU (pixel {gpu['pixel']}): screen weight of V1 {gpu['screen_weight_B']:.7f}, "
        f"affine depth {gpu['affine_depth']:.7f}, perspective-correct depth "
        f"{gpu['correct_depth']:.7f}"]
    p = os.path.join(stage, "segment_example.txt")
    write_text(p, "\n".join(text) + "\n")
    files.append(p)
    summary = {"scenes": {r.scene.name: r.stats for r in results},
               "segment_example": {"affine_depth": str(ex.affine_depth),
                                   "correct_depth": str(ex.correct_depth), "gpu": gpu},
               "resolution": list(resolution), "supersample": supersample}
    p = os.path.join(stage, "summary.json")
    write_text(p, json.dumps(summary, indent=2))
    files.append(p)
    summary["names"] = [os.path.basename(p) for p in files]
    return summary, text
