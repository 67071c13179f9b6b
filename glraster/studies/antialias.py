"""The antialiasing study: every way glraster can antialias an edge, against the exact area.

Scenes (:func:`builtin_scenes`), each a set of opaque, non-overlapping triangles:

- ``fan``: a star of wedges around the image centre, every other one of 36 sectors drawn:
  silhouette edges at 36 angles, meeting at a point;
- ``thin``: twelve slivers at angles spread over 180 degrees, from 0.04 to 1 px wide: the
  triangles that a single sample per pixel misses entirely;
- ``floor``: the dark squares of a checkerboard on a ground plane receding from behind the
  camera (near-clipped in clip space) to the far distance, where squares shrink below a
  pixel;
- ``checker``: the same floor with every square drawn, in two grey levels (1 and 0.35),
  as one connected mesh: most of its edges are between two colours, not silhouettes.

Every triangle has a flat value (1 in the first three scenes, whose images are then the
coverage); the background is 0. Methods (:func:`methods`), each giving an image (H, W):

- ``1 sample``: the value at the pixel centre;
- ``SSAA kxk`` (k = 2, 4, 8): render at k times the resolution, box filter (mean of k x k);
  for an MSAA count that is not a square, also the SSAA grid of that count (8: 4x2);
- ``MSAA S``: ``rasterize(samples=S)``, the mean of the values of the per-sample triangle
  ids (with every value 1, :attr:`glraster.types.Raster.coverage`), for every S > 1 the
  driver offers (``Context.sample_counts``);
- ``analytic AA``: :func:`glraster.diff.antialias.forward` applied to the 1-sample
  image: the differentiable op's blend across silhouette edges, from one sample per pixel.

The truth is the exact box-filtered image (:func:`exact_image`): the visible area of each
triangle in each pixel (:func:`glraster.reference.visible_area`, float64 polygon clipping)
times its value; with every value 1 this is :func:`glraster.reference.area_coverage`.
Errors are taken over the **edge pixels** (where more than one value is visible: the
pixels an edge crosses), as RMSE and max; elsewhere every method but a broken one is exact
(``max_off_edge`` says so). Times are medians over ``repeats`` runs of the whole method
(draw, readback, filter) after a warm-up, in rounds that run every method once (so a
slow spell of a shared machine hits all alike; in a new random order each round, so none
is always first); the topology hash of the analytic op is built once
per scene outside the timing (the mesh does not change from frame to frame).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np

from glraster import validate
from glraster.geometry import camera as cam
from glraster.geometry.window import window_to_clip
from glraster.io.atomic import atomic_write
from glraster.reference.area import visible_area

__all__ = ["AntialiasMethod", "AntialiasScene", "EDGE_EPS", "ORIENTATION", "SSAA_FACTORS",
           "builtin_scenes", "exact_image", "methods", "run_study", "ssaa_grid", "table",
           "write_figures", "write_study"]

SSAA_FACTORS = (2, 4, 8)
ORIENTATION = "upright: file row 0 is the top row (glraster array row H-1)"
# A value counts as visible in a pixel over more than EDGE_EPS of its area: the float64
# areas of interior pixels next to an edge are 1 to within a few ulps.
EDGE_EPS = 1e-9


# --------------------------------------------------------------------------- scenes


@dataclass(frozen=True)
class AntialiasScene:
    """A study scene: ``pos`` (V, 4) float32 clip space, ``tri`` (T, 3) int32, and
    ``values`` (T,) float64 the flat value (grey level) of each triangle; the background
    is 0. With every value 1 the image is the coverage."""

    name: str
    title: str
    pos: np.ndarray
    tri: np.ndarray
    values: np.ndarray = None

    def __post_init__(self):
        if self.values is None:
            object.__setattr__(self, "values", np.ones(len(self.tri)))

    def shade(self, tri_id: np.ndarray) -> np.ndarray:
        """The value seen through triangle ids of any shape (-1: background 0), float64."""
        return np.where(tri_id >= 0, self.values[np.maximum(tri_id, 0)], 0.0)


def _fan(resolution) -> AntialiasScene:
    height, width = resolution
    sectors = 36
    radius = 0.46 * min(height, width)
    centre = np.array([width / 2 + 0.17, height / 2 + 0.31])
    angles = 0.05 + 2 * np.pi * np.arange(sectors + 1) / sectors
    rim = centre + radius * np.c_[np.cos(angles), np.sin(angles)]
    xy = np.vstack([centre, rim])
    tri = np.array([[0, 1 + s, 2 + s] for s in range(0, sectors, 2)])
    return AntialiasScene("fan", f"fan: {sectors // 2} wedges, edges at {sectors} angles",
                 np.float32(window_to_clip(xy, resolution)), tri.astype(np.int32))


def _thin(resolution) -> AntialiasScene:
    height, width = resolution
    rows, cols = 3, 4
    cell = np.array([width / cols, height / rows])
    widths = np.geomspace(0.04, 1.0, rows * cols)
    angles = np.linspace(0.0, np.pi, rows * cols, endpoint=False) + 0.13
    xy = []
    for i, (w, a) in enumerate(zip(widths, angles)):
        centre = (np.array([i % cols, i // cols]) + 0.5) * cell
        d = 0.45 * min(cell) * np.array([np.cos(a), np.sin(a)])
        normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        xy += [centre - d, centre + d, centre + normal * w]
    tri = np.arange(len(xy)).reshape(-1, 3)
    return AntialiasScene("thin", "thin: 12 slivers 0.04 to 1 px wide",
                 np.float32(window_to_clip(np.array(xy), resolution)), tri.astype(np.int32))


def _floor(resolution, both_colours: bool = False) -> AntialiasScene:
    height, width = resolution
    cols, rows = 10, 24
    xs = np.linspace(-5.0, 5.0, cols + 1)
    zs = np.linspace(1.0, -40.0, rows + 1)             # from behind the camera to far away
    gx, gz = np.meshgrid(xs, zs)
    verts = np.c_[gx.ravel(), np.full(gx.size, -1.0), gz.ravel()]
    view = cam.look_at([0.0, 0.0, 0.0], [0.0, -0.35, -1.0], [0.0, 1.0, 0.0])
    proj = cam.perspective(60.0, width / height, 0.3, 100.0)
    pos = cam.project(verts, None, view, proj)
    tri, values = [], []
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 and not both_colours:
                continue
            a, b = r * (cols + 1) + c, r * (cols + 1) + c + 1
            d, e = a + cols + 1, b + cols + 1
            tri += [(a, b, e), (a, e, d)]
            values += [1.0 if (r + c) % 2 == 0 else 0.35] * 2
    if both_colours:
        return AntialiasScene("checker",
                              "checker: the floor, both colours (1 and 0.35), one mesh",
                     np.float32(pos), np.array(tri, np.int32), np.array(values))
    return AntialiasScene("floor", "floor: receding checkerboard, near-clipped",
                 np.float32(pos), np.array(tri, np.int32))


def builtin_scenes(resolution=(128, 128)) -> list[AntialiasScene]:
    """The fan, thin, floor and checker scenes framed for ``resolution`` (H, W)."""
    resolution = validate.resolution(resolution)
    return [_fan(resolution), _thin(resolution), _floor(resolution),
            _floor(resolution, both_colours=True)]


# --------------------------------------------------------------------------- methods


@dataclass(frozen=True)
class AntialiasMethod:
    """An antialiasing method: ``prepare(scene, resolution, ctx)`` returns a callable that
    renders and returns the scene's image (H, W) float64; ``samples`` per pixel (1 for the
    analytic op, which takes one sample and blends); ``kind`` one of "single", "ssaa",
    "msaa", "analytic"."""

    name: str
    samples: int
    kind: str
    prepare: object = field(repr=False)


def _box(a: np.ndarray, kx: int, ky: int) -> np.ndarray:
    """Mean of the ky x kx blocks of (ky H, kx W) -> (H, W)."""
    height, width = a.shape[0] // ky, a.shape[1] // kx
    return a.reshape(height, ky, width, kx).mean(axis=(1, 3))


def _single(scene, resolution, ctx):
    from glraster.gpu.rasterize import rasterize

    return lambda: scene.shade(rasterize(scene.pos, scene.tri, resolution, ctx=ctx,
                                         outputs=("tri_id",)).tri_id)


def _ssaa(kx, ky):
    def prepare(scene, resolution, ctx):
        from glraster.gpu.rasterize import rasterize

        big = (resolution[0] * ky, resolution[1] * kx)
        return lambda: _box(scene.shade(rasterize(scene.pos, scene.tri, big, ctx=ctx,
                                                  outputs=("tri_id",)).tri_id), kx, ky)
    return prepare


def ssaa_grid(samples: int) -> tuple[int, int]:
    """(kx, ky) of the SSAA grid with ``samples`` samples (a power of two): square when
    it can be, else twice as wide as high (8 -> 4x2)."""
    n = validate.positive_int("samples", samples).bit_length() - 1
    if 1 << n != samples:
        raise ValueError(f"samples must be a power of two, got {samples}")
    return 1 << ((n + 1) // 2), 1 << (n // 2)


def _msaa(s):
    def prepare(scene, resolution, ctx):
        from glraster.gpu.rasterize import rasterize

        # the resolve of flat values: the mean over the samples (with every value 1,
        # Raster.coverage)
        return lambda: scene.shade(rasterize(scene.pos, scene.tri, resolution, ctx=ctx,
                                             outputs=("tri_id",), samples=s).tri_id
                                   ).mean(axis=2)
    return prepare


def _analytic(scene, resolution, ctx):
    from glraster.diff.ops import ANTIALIAS, RASTERIZE
    from glraster.diff.topology_hash import antialias_construct_topology_hash

    topology = antialias_construct_topology_hash(scene.tri)

    def run():
        (rast, _), _ = RASTERIZE.forward(np.asarray(scene.pos, np.float32), tri=scene.tri,
                                         resolution=resolution, ctx=ctx, grad_db=False)
        ids = rast[..., 3].astype(np.int64) - 1           # id + 1 as a float, exact
        color = scene.shade(ids)[..., None].astype(np.float32)
        (out,), _ = ANTIALIAS.forward(color, rast, scene.pos, tri=scene.tri,
                                      topology_hash=topology, ctx=ctx)
        return out[0, ..., 0].astype(np.float64)
    return run


def methods(ctx) -> list[AntialiasMethod]:
    """Every method the context ``ctx`` can run: 1 sample, SSAA 2x2 / 4x4 / 8x8, MSAA at
    each sample count > 1 the driver offers (and an SSAA grid of the same count where it is
    not a square: 2x1, 4x2, ...), the analytic antialias op."""
    out = [AntialiasMethod("1 sample", 1, "single", _single)]
    out += [AntialiasMethod(f"SSAA {k}x{k}", k * k, "ssaa", _ssaa(k, k))
            for k in SSAA_FACTORS]
    # an SSAA grid with the sample count of each MSAA count that has no square one
    for s in ctx.sample_counts:
        kx, ky = ssaa_grid(s)
        if s > 1 and kx != ky:
            out.append(AntialiasMethod(f"SSAA {kx}x{ky}", s, "ssaa", _ssaa(kx, ky)))
    out += [AntialiasMethod(f"MSAA {s}", s, "msaa", _msaa(s))
            for s in ctx.sample_counts if s > 1]
    out.append(AntialiasMethod("analytic AA", 1, "analytic", _analytic))
    return out


# --------------------------------------------------------------------------- the study


def exact_image(scene: AntialiasScene, resolution) -> tuple[np.ndarray, np.ndarray]:
    """The exact box-filtered image of ``scene`` (H, W) float64
    (:meth:`glraster.reference.AreaFragments.resolve` of its values over background 0)
    and its edge pixels (H, W) bool: those where more than one value is visible (two
    triangles of different values, or a triangle and the background, each over more than
    EDGE_EPS of the pixel). With every value 1: the pixels with 0 < area < 1."""
    height, width = resolution
    frags = visible_area(scene.pos, scene.tri, resolution)
    image = frags.resolve(scene.values, 0.0)
    keep = frags.area > EDGE_EPS
    pixel = (frags.y * width + frags.x)[keep]
    values = scene.values[frags.tri_id[keep]]
    low = np.full(height * width, np.inf)
    high = np.full(height * width, -np.inf)
    np.minimum.at(low, pixel, values)
    np.maximum.at(high, pixel, values)
    coverage = frags.coverage.ravel()
    partial = (coverage > EDGE_EPS) & (coverage < 1 - EDGE_EPS)
    low[partial] = np.minimum(low[partial], 0.0)
    high[partial] = np.maximum(high[partial], 0.0)
    return image, (high > low).reshape(height, width)


def _errors(image: np.ndarray, truth: np.ndarray, edge: np.ndarray) -> dict:
    err = image - truth
    return {"rmse": float(np.sqrt(np.mean(err[edge] ** 2))) if edge.any() else 0.0,
            "max": float(np.abs(err[edge]).max()) if edge.any() else 0.0,
            "max_off_edge": float(np.abs(err[~edge]).max()) if (~edge).any() else 0.0}


def run_study(resolution=(128, 128), repeats: int = 5, ctx=None, scenes=None) -> dict:
    """Run every method on every scene; return the results (JSON-ready, plus images).

    Returns:
        {"resolution", "repeats", "renderer", "scenes": {name: {"title", "triangles",
        "edge_pixels", "exact_s"}}, "methods": [{"name", "samples", "kind",
        "scenes": {name: {"rmse", "max", "max_off_edge", "time_s"}}, "mean_rmse"}] (ordered
        by mean RMSE, smallest first), "msaa_vs_ssaa": [{"samples", "msaa", "ssaa",
        "time_ratio", "rmse_ratio"}], and "_images": {scene: {"truth", "edge", method:
        (H, W)}}
        (not serialised).
    """
    from glraster.gpu.context import default_context

    ctx = ctx or default_context()
    resolution = validate.resolution(resolution)
    repeats = validate.positive_int("repeats", repeats)
    scenes = scenes if scenes is not None else builtin_scenes(resolution)
    all_methods = methods(ctx)
    result = {"resolution": list(resolution), "repeats": repeats, "renderer": ctx.renderer,
              "backend": ctx.backend, "scenes": {}, "methods": [], "msaa_vs_ssaa": []}
    images = {}
    exact_image(scenes[0], (16, 16))                           # compile (numba) untimed
    for scene in scenes:
        t0 = time.perf_counter()
        truth, edge = exact_image(scene, resolution)
        elapsed = time.perf_counter() - t0
        result["scenes"][scene.name] = {"title": scene.title, "triangles": len(scene.tri),
                                        "edge_pixels": int(edge.sum()),
                                        "exact_s": elapsed}
        images[scene.name] = {"truth": truth, "edge": edge}
    # Every (method, scene) is warmed up, then timed in rounds that run each once, so that
    # a slow spell of a shared machine hits all methods alike (median over the rounds).
    runs = {(m.name, scene.name): m.prepare(scene, resolution, ctx)
            for m in all_methods for scene in scenes}
    for key, run in runs.items():
        images[key[1]][key[0]] = run()
    times = {key: [] for key in runs}
    keys = list(runs)
    order = np.random.default_rng(0)
    for _ in range(repeats):
        for i in order.permutation(len(keys)):       # a new order each round
            t0 = time.perf_counter()
            runs[keys[i]]()
            times[keys[i]].append(time.perf_counter() - t0)
    for m in all_methods:
        row = {"name": m.name, "samples": m.samples, "kind": m.kind, "scenes": {}}
        for scene in scenes:
            stats = _errors(images[scene.name][m.name], images[scene.name]["truth"],
                            images[scene.name]["edge"])
            stats["time_s"] = float(np.median(times[m.name, scene.name]))
            row["scenes"][scene.name] = stats
        row["mean_rmse"] = float(np.mean([s["rmse"] for s in row["scenes"].values()]))
        row["total_time_s"] = float(sum(s["time_s"] for s in row["scenes"].values()))
        result["methods"].append(row)
    result["methods"].sort(key=lambda r: r["mean_rmse"])
    by_name = {r["name"]: r for r in result["methods"]}
    for m in all_methods:
        kx, ky = ssaa_grid(m.samples)
        if m.kind == "msaa":
            ms, ss = by_name[m.name], by_name[f"SSAA {kx}x{ky}"]
            result["msaa_vs_ssaa"].append({
                "samples": m.samples, "msaa": m.name, "ssaa": ss["name"],
                "time_ratio": ss["total_time_s"] / ms["total_time_s"],
                "rmse_ratio": ms["mean_rmse"] / ss["mean_rmse"] if ss["mean_rmse"] else None})
    result["_images"] = images
    return result


def table(result: dict) -> list[str]:
    """The study as text lines: one row per method (ordered by error), per scene the edge
    RMSE / max and the time."""
    names = list(result["scenes"])
    head = f"{'method':<12} {'S':>3}  " + "  ".join(f"{n + ' rmse / max / ms':>26}" for n in names)
    lines = [head, "-" * len(head)]
    for r in result["methods"]:
        cells = [f"{r['scenes'][n]['rmse']:8.4f} / {r['scenes'][n]['max']:.3f} / "
                 f"{1e3 * r['scenes'][n]['time_s']:6.1f}" for n in names]
        lines.append(f"{r['name']:<12} {r['samples']:>3}  " + "  ".join(f"{c:>26}" for c in cells))
    for c in result["msaa_vs_ssaa"]:
        rmse = (f"{c['rmse_ratio']:.2f}x the error" if c["rmse_ratio"] is not None
                else "both exact")
        lines.append(f"{c['msaa']} against {c['ssaa']} ({c['samples']} samples each): SSAA "
                     f"time / MSAA time {c['time_ratio']:.2f}, MSAA has {rmse} of SSAA")
    for n, s in result["scenes"].items():
        lines.append(f"{n}: {s['triangles']} triangles, {s['edge_pixels']} edge pixels, exact "
                     f"image (visible areas) in {1e3 * s['exact_s']:.0f} ms")
    return lines


# --------------------------------------------------------------------------- writing


def _meta(what: str) -> dict:
    return {"title": f"glraster antialias-study: {what}", "description": ORIENTATION}


def _zoom_window(edge: np.ndarray, size: int) -> tuple[slice, slice]:
    """A size x size crop centred on the edge pixel (of ``edge`` (H, W) bool) nearest a
    point up and right of the centre (the fan's edges are clear of each other there)."""
    height, width = edge.shape
    edge = np.argwhere(edge)
    target = np.array([height / 2 + 0.4 * height / 2 * 0.6, width / 2 + 0.4 * width / 2 * 0.8])
    y, x = edge[np.argmin(np.sum((edge - target) ** 2, axis=1))] if len(edge) else target
    size = min(size, height, width)
    y0 = int(np.clip(y - size // 2, 0, height - size))
    x0 = int(np.clip(x - size // 2, 0, width - size))
    return slice(y0, y0 + size), slice(x0, x0 + size)


def write_figures(result: dict, out_dir) -> list[str]:
    """``antialias_error_time.png`` (edge RMSE and max against time, per method and scene)
    and ``antialias_zoom.png`` (one zoomed fan edge per method, ordered by error, with the
    error against the exact area below). Returns the paths."""
    from pathlib import Path

    from glraster.io import figures

    out_dir = Path(out_dir)
    rows = result["methods"]
    names = [r["name"] for r in rows]
    # colours by method, in a fixed order (fewest samples first), whatever the ranking
    colors = figures.colors(sorted(names, key=lambda n: (
        next(r["samples"] for r in rows if r["name"] == n), n)))
    markers = dict(zip(result["scenes"], "osD^v"))
    files = []

    p = out_dir / "antialias_error_time.png"
    with figures.figure(p, figsize=(12, 5.2), **_meta("error against time")) as fig:
        axes = fig.subplots(1, 2)
        for ax, key, label in ((axes[0], "rmse", "RMSE over edge pixels"),
                               (axes[1], "max", "max |error| over edge pixels")):
            for r in rows:
                for scene, s in r["scenes"].items():
                    ax.scatter(1e3 * s["time_s"], max(s[key], 1e-6), color=colors[r["name"]],
                               marker=markers[scene], s=36, edgecolor="black", linewidth=0.4)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("time per frame (ms, median)")
            ax.set_ylabel(f"{label} (1 = a whole pixel of value 1)")
            ax.grid(True, which="both")
        from matplotlib.lines import Line2D

        method_handles = [Line2D([], [], linestyle="", marker="o", color=colors[n],
                                 markeredgecolor="black", label=f"{n} (mean RMSE "
                                 f"{r['mean_rmse']:.4f})") for n, r in zip(names, rows)]
        scene_handles = [Line2D([], [], linestyle="", marker=mk, color="gray", label=sc)
                         for sc, mk in markers.items()]
        axes[1].legend(handles=method_handles + scene_handles, loc="center left",
                       bbox_to_anchor=(1.02, 0.5), title="method (by error) / scene")
        h, w = result["resolution"]
        fig.suptitle(f"Antialiasing against the exact box-filtered image ({w}x{h}, "
                     f"{result['renderer']})")
    files.append(str(p))

    images = result["_images"]["fan"] if "fan" in result["_images"] else next(
        iter(result["_images"].values()))
    truth = images["truth"]
    ys, xs = _zoom_window(images["edge"], 14)
    p = out_dir / "antialias_zoom.png"
    panels = ["truth"] + names
    with figures.figure(p, figsize=(1.75 * len(panels), 4.2), **_meta("zoomed edge")) as fig:
        axes = fig.subplots(2, len(panels), squeeze=False)
        for col, name in enumerate(panels):
            crop = images[name][ys, xs]
            axes[0, col].imshow(crop[::-1], cmap="gray", vmin=0, vmax=1)
            title = "exact" if name == "truth" else name
            axes[0, col].set_title(title)
            err = crop - truth[ys, xs]
            im = axes[1, col].imshow(err[::-1], cmap="RdBu_r", vmin=-0.5, vmax=0.5)
            if name != "truth":
                axes[1, col].set_title(f"max |err| {np.abs(err).max():.3f}", fontsize=8)
            for ax in axes[:, col]:
                ax.set_xticks([])
                ax.set_yticks([])
        axes[0, 0].set_ylabel("image")
        axes[1, 0].set_ylabel("error")
        fig.colorbar(im, ax=axes[1, :].tolist(), shrink=0.9, label="image - exact")
        fig.suptitle(f"One fan edge, {xs.stop - xs.start}x{ys.stop - ys.start} pixels from "
                     f"({xs.start}, {ys.start}); methods ordered by error")
    files.append(str(p))
    return files


def write_study(out_dir="out/antialias", resolution=(128, 128), repeats: int = 5,
                ctx=None) -> dict:
    """Run the study and write under ``out_dir``: ``antialias.json`` (every number),
    ``antialias_error_time.png`` and ``antialias_zoom.png``, all atomically. Returns the
    result (without images) with "files" and "text" (the table) added."""
    from pathlib import Path

    result = run_study(resolution, repeats, ctx)
    files = write_figures(result, out_dir)
    result.pop("_images")
    path = Path(out_dir) / "antialias.json"
    with atomic_write(path) as tmp:
        with open(tmp, "w") as fh:
            json.dump(result, fh, indent=2)
    files.append(str(path))
    result["files"] = files
    result["text"] = table(result)
    return result
