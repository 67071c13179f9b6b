"""Run time against error: every method on benchmark scenes, with the fill limit and pyrender.

A *case* is (method, scene, resolution, triangle count). For each case the benchmark
records, on one context:

- ``first_ms``: the first call on a fresh context (shader compile, framebuffer and buffer
  creation included);
- ``warm_ms`` (median) and ``warm_spread_ms`` (min, max) over ``repeats`` warm calls;
- ``fill_ms`` and ``fill_ratio``: the bare moderngl draw of the same triangles into the
  same targets (:mod:`glraster.studies.fill_limit`), timed interleaved with the method (A/B pairs),
  and the median of the per-pair ratios;
- error against the float64 reference (when the image is at most ``max_reference_pixels``):
  max / 99.9th percentile / mean over the pixels both cover with the same triangle, and the
  worst error / tolerance of the method's error model;
- ``peak_host_mib``: peak host memory allocated during one warm call (tracemalloc: numpy
  arrays and Python objects; llvmpipe's own buffers are not traced) and ``target_mib`` the
  size of the render targets;
- for hw, the **pyrender** peer: a depth-only render of the same mesh and camera on the
  same driver, timed inside a subprocess (PYOPENGL_PLATFORM=egl), against glraster's
  depth-only call.

Scenes are real meshes seen through a perspective camera (so w varies and pyrender can
render the same thing): ``terrain`` (a wavy height field, few overlaps) and ``shards``
(randomly oriented triangles in a box, overdraw). ``headline()`` measures the figures the
README quotes; ``skips()`` measures each "skip what is not needed" switch on and off.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from dataclasses import asdict, dataclass, field

import numpy as np

from glraster.geometry import camera as cam
from glraster.geometry.shapes import icosphere
from glraster import reference
from glraster.reference import kernels as reference_kernels
from glraster.verify.compare import compare
from glraster.gpu.context import Context
from glraster.studies.fill_limit import FillLimit
from glraster.gpu.methods import METHODS, error_model
from glraster.gpu.rasterize import rasterize

FOVY_DEG = 50.0
NEAR, FAR = 0.1, 20.0


@dataclass
class BenchScene:
    """A benchmark mesh and camera.

    vertices : (V, 3) float64 world positions; faces : (T, 3) int32
    view, proj : (4, 4) float64 OpenGL matrices; pos : (V, 4) float32 clip positions
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    view: np.ndarray
    proj: np.ndarray
    pos: np.ndarray


def make_bench_scene(name: str, count: int, aspect: float = 1.0, seed: int = 0) -> BenchScene:
    """The ``name`` scene ("terrain" or "shards") with about ``count`` triangles (exactly
    ``count`` for shards; terrain rounds to a grid, at least 1 triangle)."""
    rng = np.random.default_rng(seed)
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    if name == "terrain":
        if count == 1:
            vertices = np.array([[-1.0, 0.0, -1.0], [1.0, 0.2, -1.0], [0.0, 0.1, 1.0]])
            faces = np.array([[0, 1, 2]])
        else:
            n = max(1, int(round(np.sqrt(count / 2))))
            xs, zs = np.meshgrid(np.linspace(-2, 2, n + 1), np.linspace(-2, 2, n + 1))
            ys = 0.15 * np.sin(3 * xs) * np.cos(2 * zs) + 0.05 * rng.standard_normal(xs.shape)
            vertices = np.stack([xs, ys, zs], -1).reshape(-1, 3)
            i, j = np.meshgrid(np.arange(n), np.arange(n))
            v00 = (j * (n + 1) + i).ravel()
            v10, v01, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
            faces = np.concatenate([np.stack([v00, v01, v11], 1), np.stack([v00, v11, v10], 1)])
        eye, target = (0.0, 2.2, 3.2), (0.0, -0.2, 0.0)
    elif name == "shards":
        centers = rng.uniform(-1.5, 1.5, (count, 1, 3))
        size = 1.2 / max(count, 1) ** (1 / 3)
        vertices = (centers + rng.normal(0, size, (count, 3, 3))).reshape(-1, 3)
        faces = np.arange(3 * count).reshape(count, 3)
        eye, target = (0.0, 0.5, 4.0), (0.0, 0.0, 0.0)
    else:
        raise ValueError(f"scene must be 'terrain' or 'shards', got {name!r}")
    view = cam.look_at(eye, target)
    proj = cam.perspective(FOVY_DEG, aspect, NEAR, FAR)
    pos = cam.project(vertices, view=view, proj=proj)
    return BenchScene(name, vertices, faces.astype(np.int32), view, proj, pos)


@dataclass
class CaseResult:
    """One benchmark case (see the module docstring for every field)."""

    method: str
    scene: str
    resolution: tuple
    triangles: int
    first_ms: float
    warm_ms: float
    warm_spread_ms: tuple
    fill_ms: float
    fill_ratio: float
    peak_host_mib: float
    target_mib: float
    error: dict = field(default_factory=dict)
    pyrender: dict = field(default_factory=dict)


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def interleaved(fn_a, fn_b, repeats: int):
    """Time ``fn_a`` and ``fn_b`` alternately (A B A B ...), ``repeats`` pairs after one
    warm-up pair. Returns (times_a, times_b) in seconds, (repeats,) arrays each."""
    fn_a(), fn_b()
    ta, tb = [], []
    for _ in range(repeats):
        ta.append(_timed(fn_a)[0])
        tb.append(_timed(fn_b)[0])
    return np.array(ta), np.array(tb)


def _error_stats(raster, ref, method, ctx) -> dict:
    rep = compare(raster, ref, error_model(method, ctx))
    out = {"coverage_mismatch": rep.coverage_mismatch, "tri_id_mismatch": rep.tri_id_mismatch}
    for name, v in rep.values.items():
        out[name] = {"max": v.max, "p999": v.p999, "mean": v.mean,
                     "worst_ratio": v.worst_ratio, "over_tolerance": v.over_tolerance}
    return out


_PYRENDER_WORKER = r"""
import json, sys, time
import numpy as np
import pyrender, trimesh
d = np.load(sys.argv[1])
scene = pyrender.Scene()
scene.add(pyrender.Mesh.from_trimesh(trimesh.Trimesh(d["vertices"], d["faces"], process=False), smooth=False))
H, W = (int(x) for x in d["resolution"])
scene.add(pyrender.PerspectiveCamera(yfov=float(d["yfov"]), znear=float(d["near"]),
          zfar=float(d["far"]), aspectRatio=W / H), pose=d["pose"])
t0 = time.perf_counter()
r = pyrender.OffscreenRenderer(W, H)
depth = r.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
first = time.perf_counter() - t0
times = []
for _ in range(int(d["repeats"])):
    t = time.perf_counter()
    r.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
    times.append(time.perf_counter() - t)
r.delete()
print(json.dumps({"first_ms": first * 1e3, "warm_ms": float(np.median(times)) * 1e3,
                  "warm_spread_ms": [min(times) * 1e3, max(times) * 1e3],
                  "covered": int((depth > 0).sum())}))
"""


PYRENDER_MISSING = ("the pyrender peer needs pyrender and trimesh (the [mesh] extra: pip "
                    "install 'glraster[mesh]'); or pass --no-pyrender to skip it")


def pyrender_installed() -> bool:
    """Whether the pyrender peer's packages can be imported (found, not imported here)."""
    import importlib.util

    return all(importlib.util.find_spec(name) is not None for name in ("pyrender", "trimesh"))


def pyrender_time(scene: BenchScene, resolution, repeats: int = 5, timeout: float = 600) -> dict:
    """Depth-only pyrender render of ``scene`` at ``resolution`` (H, W) in a subprocess
    (PYOPENGL_PLATFORM=egl): {"first_ms", "warm_ms", "warm_spread_ms", "covered"}."""
    height, width = resolution
    with tempfile.TemporaryDirectory(prefix="glraster-bench-") as tmp:
        src = os.path.join(tmp, "scene.npz")
        np.savez(src, vertices=scene.vertices, faces=scene.faces.astype(np.int64),
                 resolution=[height, width], yfov=np.radians(FOVY_DEG), near=NEAR, far=FAR,
                 pose=np.linalg.inv(scene.view), repeats=repeats)
        env = dict(os.environ, PYOPENGL_PLATFORM="egl")
        proc = subprocess.run([sys.executable, "-c", _PYRENDER_WORKER, src], env=env,
                              capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"pyrender subprocess failed:\n{tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_case(method, scene: BenchScene, resolution, *, backend="egl", repeats=5, ref=None,
             with_pyrender=False) -> CaseResult:
    """Measure one case on a fresh context (so that ``first_ms`` includes compiling)."""
    ctx = Context(backend)
    try:
        call = lambda: rasterize(scene.pos, scene.faces, resolution, ctx=ctx, method=method)  # noqa: E731
        first, raster = _timed(call)
        fill = FillLimit(ctx, scene.pos, scene.faces, resolution)
        t_method, t_fill = interleaved(call, fill.run, repeats)
        fill.release()
        tracemalloc.start()
        call()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        height, width = resolution
        target_bytes = height * width * (3 * 4 + 3 * 4 + 4 + 4)
        result = CaseResult(
            method=method, scene=scene.name, resolution=tuple(resolution),
            triangles=len(scene.faces), first_ms=first * 1e3,
            warm_ms=float(np.median(t_method)) * 1e3,
            warm_spread_ms=(float(t_method.min()) * 1e3, float(t_method.max()) * 1e3),
            fill_ms=float(np.median(t_fill)) * 1e3,
            fill_ratio=float(np.median(t_method / t_fill)),
            peak_host_mib=peak / 2**20, target_mib=target_bytes / 2**20,
        )
        if ref is not None:
            result.error = _error_stats(raster, ref, method, ctx)
        if with_pyrender:
            depth_call = lambda: rasterize(scene.pos, scene.faces, resolution, ctx=ctx,  # noqa: E731
                                           method=method, outputs=("depth",))
            depth_call()
            t_depth = np.array([_timed(depth_call)[0] for _ in range(repeats)])
            peer = pyrender_time(scene, resolution, repeats)
            peer["glraster_depth_ms"] = float(np.median(t_depth)) * 1e3
            peer["ratio"] = peer["warm_ms"] / peer["glraster_depth_ms"]
            result.pyrender = peer
        return result
    finally:
        ctx.release()


PRESETS = {
    "quick": dict(methods=tuple(METHODS), scenes=("terrain",), resolutions=(256, 1024),
                  counts=(1, 20000), repeats=5),
    "full": dict(methods=tuple(METHODS), scenes=("terrain", "shards"),
                 resolutions=(256, 1024, 4096), counts=(1, 1000, 20000, 1000000), repeats=7),
}


def run(preset="quick", *, backend="egl", max_reference_pixels=1 << 24, progress=None,
        with_pyrender=True, summaries=True, **overrides) -> dict:
    """Run a preset (see PRESETS; keyword arguments override its fields).

    Returns {"cases": [CaseResult as dict, ...], "headline": ..., "skips": ...,
    "reference": [...], "settings": ...}. ``progress(i, n, label)`` is called before each
    step. ``summaries=False`` skips :func:`headline` and :func:`skips` (empty dicts).
    """
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    settings = dict(PRESETS[preset], **overrides)
    unknown = set(settings["methods"]) - set(METHODS)
    if unknown:
        raise ValueError(f"methods has unknown names {sorted(unknown)}; choose from {sorted(METHODS)}")
    grid = [(s, r, c) for s in settings["scenes"] for r in settings["resolutions"]
            for c in settings["counts"]]
    steps = len(grid) * (1 + len(settings["methods"])) + (2 if summaries else 0)
    step = 0

    def tick(label):
        nonlocal step
        step += 1
        if progress:
            progress(step, steps, label)

    cases, refs = [], []
    for scene_name, size, count in grid:
        resolution = (size, size)
        scene = make_bench_scene(scene_name, count)
        tick(f"reference {scene_name} {size}x{size} {len(scene.faces)} tris")
        ref = None
        if size * size <= max_reference_pixels:
            seconds, ref = _timed(lambda: reference.rasterize(scene.pos, scene.faces, resolution))
            refs.append({"scene": scene_name, "resolution": resolution,
                         "triangles": len(scene.faces), "seconds": seconds,
                         "mpix_per_s": size * size / seconds / 1e6})
        for method in settings["methods"]:
            tick(f"{method} {scene_name} {size}x{size} {len(scene.faces)} tris")
            cases.append(asdict(run_case(
                method, scene, resolution, backend=backend, repeats=settings["repeats"],
                ref=ref, with_pyrender=with_pyrender and method == "hw")))
        del ref
    head, skip = {}, {}
    if summaries:
        tick("headline figures")
        head = headline(backend=backend, repeats=max(settings["repeats"], 9),
                        with_pyrender=with_pyrender)
        tick("skip switches")
        skip = skips(backend=backend, repeats=settings["repeats"])
    return {"settings": {"preset": preset, **{k: list(v) if isinstance(v, tuple) else v
                                               for k, v in settings.items()}},
            "cases": cases, "reference": refs, "headline": head, "skips": skip}


def _round_robin(fns, repeats: int) -> list:
    """Time ``fns`` in turn (A B C ... A B C ...), ``repeats`` rounds after one warm-up
    round: one (repeats,) array of seconds per function, entry i of each from round i."""
    for fn in fns:
        fn()
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, t in zip(fns, times):
            t.append(_timed(fn)[0])
    return [np.array(t) for t in times]


def _ratio_stats(a: np.ndarray, b: np.ndarray) -> dict:
    """Median, min and max of the per-round ratios a / b ((repeats,) arrays)."""
    ratio = a / b
    return {"median": float(np.median(ratio)), "min": float(ratio.min()),
            "max": float(ratio.max()), "pairs": int(len(ratio))}


def headline(*, backend="egl", repeats=9, resolution=(1024, 1024), count=20000,
             with_pyrender=True) -> dict:
    """The README figures: hw against two yardsticks drawing the same float targets, the
    fill limit (:class:`FillLimit`) and the lean draw (:class:`LeanDraw`: plain vertex
    attributes, preallocated outputs), with ``rasterize`` timed both returning new arrays
    and filling earlier ones (``out=``); all four timed in interleaved rounds, each ratio
    the median and spread of its per-round ratios over ``repeats`` rounds. Then the 64x64
    one-triangle warm overhead (also with ``out=``), the reference throughput, and
    pyrender vs glraster (depth only; ``"pyrender": None`` without ``with_pyrender``)."""
    from glraster.studies.fill_limit import LeanDraw

    scene = make_bench_scene("terrain", count)
    ctx = Context(backend)
    try:
        fill = FillLimit(ctx, scene.pos, scene.faces, resolution)
        lean = LeanDraw(ctx, scene.pos, scene.faces, resolution)
        call = lambda: rasterize(scene.pos, scene.faces, resolution, ctx=ctx)  # noqa: E731
        previous = call()
        call_out = lambda: rasterize(scene.pos, scene.faces, resolution, ctx=ctx,  # noqa: E731
                                     out=previous)
        t_hw, t_out, t_fill, t_lean = _round_robin((call, call_out, fill.run, lean.run), repeats)
        fill.release()
        lean.release()
        one = make_bench_scene("terrain", 1)
        small = lambda: rasterize(one.pos, one.faces, (64, 64), ctx=ctx)  # noqa: E731
        for _ in range(20):
            small()
        t_small = np.array([_timed(small)[0] for _ in range(200)])
        small_previous = small()
        small_out = lambda: rasterize(one.pos, one.faces, (64, 64), ctx=ctx,  # noqa: E731
                                      out=small_previous)
        for _ in range(20):
            small_out()
        t_small_out = np.array([_timed(small_out)[0] for _ in range(200)])
        overhead = {}
        for method in METHODS:
            f = lambda m=method: rasterize(one.pos, one.faces, (64, 64), ctx=ctx, method=m)  # noqa: E731
            for _ in range(10):
                f()
            overhead[method] = float(np.median([_timed(f)[0] for _ in range(100)])) * 1e3
        depth_call = lambda: rasterize(scene.pos, scene.faces, resolution, ctx=ctx,  # noqa: E731
                                       outputs=("depth",))
        depth_call()
        t_depth = np.array([_timed(depth_call)[0] for _ in range(repeats)])
    finally:
        ctx.release()
    reference.rasterize(scene.pos, scene.faces, resolution)  # loads the compiled kernels
    t_ref = np.array([_timed(lambda: reference.rasterize(scene.pos, scene.faces, resolution))[0]
                      for _ in range(5)])
    peer = pyrender_time(scene, resolution, repeats) if with_pyrender else None
    pixels = resolution[0] * resolution[1]
    t_depth_ms = float(np.median(t_depth)) * 1e3
    return {
        "scene": f"terrain {len(scene.faces)} triangles at {resolution[0]}x{resolution[1]} (HxW)",
        "hw_ms": float(np.median(t_hw)) * 1e3, "fill_ms": float(np.median(t_fill)) * 1e3,
        "hw_out_ms": float(np.median(t_out)) * 1e3, "lean_ms": float(np.median(t_lean)) * 1e3,
        "hw_over_fill": _ratio_stats(t_hw, t_fill),
        "hw_over_lean": _ratio_stats(t_hw, t_lean),
        "hw_out_over_fill": _ratio_stats(t_out, t_fill),
        "hw_out_over_lean": _ratio_stats(t_out, t_lean),
        "overhead_64x64_ms": {"median": float(np.median(t_small)) * 1e3,
                              "p90": float(np.percentile(t_small, 90)) * 1e3,
                              "median_out": float(np.median(t_small_out)) * 1e3,
                              "per_method": overhead},
        "reference_mpix_per_s": {"median": pixels / float(np.median(t_ref)) / 1e6,
                                 "best": pixels / float(t_ref.min()) / 1e6},
        "pyrender": None if peer is None else {
            "pyrender_depth_ms": peer["warm_ms"], "glraster_depth_ms": t_depth_ms,
            "glraster_all_outputs_ms": float(np.median(t_hw)) * 1e3,
            "speedup_depth_only": peer["warm_ms"] / t_depth_ms},
    }


def skips(*, backend="egl", repeats=5, resolution=(1024, 1024), count=20000) -> dict:
    """Each "skip what the scene does not need" switch, on against off (median ms,
    interleaved): output subsets, the affine path, culling, the caches, the reference's
    span traversal (vs all pixels of the bounding boxes)."""
    out = {}
    scene = make_bench_scene("terrain", count)
    ctx = Context(backend)
    try:
        def ab(label, fn_on, fn_off):
            on, off = interleaved(fn_on, fn_off, repeats)
            out[label] = {"on_ms": float(np.median(on)) * 1e3, "off_ms": float(np.median(off)) * 1e3}

        pos, tri = scene.pos, scene.faces
        ab("outputs tri_id only vs all",
           lambda: rasterize(pos, tri, resolution, ctx=ctx, outputs=("tri_id",)),
           lambda: rasterize(pos, tri, resolution, ctx=ctx))
        ortho = pos.copy()
        ortho[:, :3] /= ortho[:, 3:4]
        ortho[:, 3] = 1.0
        ab("affine path (equal w)",
           lambda: rasterize(ortho, tri, resolution, ctx=ctx),
           lambda: rasterize(ortho, tri, resolution, ctx=ctx, affine=False))
        # half of the triangles behind the camera or off screen
        far = np.concatenate([pos, pos * np.array([1, 1, 1, -1], np.float32)])
        tri2 = np.concatenate([tri, tri + len(pos)])
        for method in ("hw", "homogeneous"):
            ab(f"{method}: host culling (half the triangles behind the eye)",
               lambda m=method: rasterize(far, tri2, resolution, ctx=ctx, method=m, cull=True),
               lambda m=method: rasterize(far, tri2, resolution, ctx=ctx, method=m, cull=False))
        # a closed mesh seen from outside (about two thirds of it facing away): the back
        # faces dropped before upload against GL_CULL_FACE alone (cull_backfaces=True both)
        vertices, faces = icosphere(6)       # 81,920 triangles
        view = cam.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0))
        sphere = cam.project(vertices, view=view, proj=cam.perspective(FOVY_DEG, 1.0, NEAR, FAR))
        for method in ("hw", "homogeneous"):
            ab(f"{method}: host back-face culling (closed sphere, seen from outside)",
               lambda m=method: rasterize(sphere, faces, resolution, ctx=ctx, method=m,
                                          cull_backfaces=True, cull=True),
               lambda m=method: rasterize(sphere, faces, resolution, ctx=ctx, method=m,
                                          cull_backfaces=True, cull=False))
    finally:
        ctx.release()
    # caches: a warm call against a call on a fresh context (compile + allocation)
    first = []
    for _ in range(3):
        c = Context(backend)
        first.append(_timed(lambda: rasterize(scene.pos, scene.faces, resolution, ctx=c))[0])
        c.release()
    c = Context(backend)
    rasterize(scene.pos, scene.faces, resolution, ctx=c)
    warm = [_timed(lambda: rasterize(scene.pos, scene.faces, resolution, ctx=c))[0]
            for _ in range(3)]
    c.release()
    out["cached programs/framebuffers/buffers"] = {
        "on_ms": float(np.median(warm)) * 1e3, "off_ms": float(np.median(first)) * 1e3}
    # the reference: exact row spans (covered pixels only) against testing every candidate
    # of the bounding boxes in float64, both compiled, coverage only
    ts = reference.setup(scene.pos, scene.faces, resolution, "llvmpipe")
    every = np.arange(len(ts.bbox))
    none = np.zeros(len(every), bool)
    band = np.zeros(resolution[0] * resolution[1], bool)
    spans = lambda: reference_kernels.fixed_point_spans(every[ts.fixed_ok], ts.fixed, ts.bbox)  # noqa: E731
    candidates = lambda: reference_kernels.float_spans(  # noqa: E731
        every, ts.adj, ts.det, ts.depth_plane, ts.bbox, ~ts.culled, none, 0.0, resolution[1], band)
    t_spans, t_candidates = interleaved(spans, candidates, repeats)
    out["reference: row spans vs testing every bbox candidate (coverage only)"] = {
        "on_ms": float(np.median(t_spans)) * 1e3, "off_ms": float(np.median(t_candidates)) * 1e3}
    return out


EPS32, EPS64 = 2.0**-24, 2.0**-53     # float32 and float64 rounding, the error axis' marks


class _ParetoCases:
    """What the Pareto figure shows, apart from how it is drawn: the cases with a warm time
    and a persp error, their methods, scenes, resolutions and triangle counts, the error
    axis' range, and which case is Pareto-optimal."""

    def __init__(self, result: dict):
        import math

        self.cases = [c for c in result["cases"]
                      if (c.get("error") or {}).get("persp") and c.get("warm_ms") is not None]
        cases, settings = self.cases, result.get("settings", {})
        self.methods = [m for m in METHODS if any(c["method"] == m for c in cases)]
        self.methods += sorted({c["method"] for c in cases} - set(self.methods))
        self.scenes = [s for s in settings.get("scenes", []) if any(c["scene"] == s for c in cases)]
        self.scenes += sorted({c["scene"] for c in cases} - set(self.scenes))
        self.sizes = sorted({tuple(c["resolution"]) for c in cases},
                            key=lambda r: (r[0] * r[1], r))
        self._requested = sorted(settings.get("counts") or [])
        self.counts = sorted({self.count_key(c["triangles"]) for c in cases})
        self.errors = np.array([c["error"]["persp"]["max"] for c in cases], dtype=float)
        finite = self.errors[np.isfinite(self.errors)]
        positive = finite[finite > 0]
        self.lo = 10.0 ** (math.floor(math.log10(min([EPS32, *positive]))) - 1)
        self.hi = 10.0 ** (math.ceil(math.log10(max([1e-2, *finite]))) + 0.3)
        self.zero_at, self._top_at = self.lo * 2, self.hi / 2
        self._by_case = {}                      # (scene, resolution, count) -> its cases
        for c in cases:
            self._by_case.setdefault(self.case_key(c), []).append(c)

    def count_key(self, n: int) -> int:
        """The requested count a case was built for (scenes round it)."""
        import math

        if not self._requested:
            return n
        return min(self._requested,
                   key=lambda r: abs(math.log(max(n, 1)) - math.log(max(r, 1))))

    def case_key(self, c) -> tuple:
        return (c["scene"], tuple(c["resolution"]), self.count_key(c["triangles"]))

    def shown(self, c) -> float:
        """The case's max persp error where it is drawn: non-finite at the top, an exact 0
        near the bottom."""
        import math

        e = c["error"]["persp"]["max"]
        return self._top_at if not math.isfinite(e) else (self.zero_at if e <= 0 else e)

    def pareto_optimal(self, c) -> bool:
        """No other method is both faster and at least as accurate on the same case."""
        t, e = c["warm_ms"], self.shown(c)
        return not any(o is not c and o["warm_ms"] <= t and self.shown(o) <= e
                       and (o["warm_ms"] < t or self.shown(o) < e)
                       for o in self._by_case[self.case_key(c)])


def _count_label(n: int) -> str:
    for div, unit in ((10**6, "M"), (10**3, "k")):
        if n >= div:
            return f"{n / div:g}{unit}"
    return f"{n}"


def pareto_plot(result: dict, path: str) -> None:
    """Warm time against max persp error, log-log, one panel per scene and resolution.

    In each panel every method is a line through its cases in increasing triangle count
    (one marker shape per count); a filled marker is Pareto-optimal for its case (no other
    method is both faster and at least as accurate on the same scene, resolution and
    count), a hollow one is dominated. The error axis spans the float64 rounding level:
    dotted lines mark 2^-24 (float32) and 2^-53 (float64); an exact 0 is drawn at the
    bottom. No text labels inside the panels (legends only), so nothing overlaps.
    Written through :func:`glraster.io.figures.figure` (Agg, atomic, with metadata)."""
    from glraster.io import figures

    pc = _ParetoCases(result)
    markers = dict(zip(pc.counts, "osD^vPX*<>" * (1 + len(pc.counts) // 10)))
    color = figures.colors(METHODS)
    color.update({m: figures.PALETTE[(len(METHODS) + i) % len(figures.PALETTE)]
                  for i, m in enumerate(m for m in pc.methods if m not in color)})
    nrows, ncols = max(1, len(pc.scenes)), max(1, len(pc.sizes))
    title = "glraster methods: warm time per call against max persp error (llvmpipe)"
    legend_width = 0.0 if ncols >= 3 else 3.6
    with figures.figure(path, figsize=(0.8 + 4.0 * ncols + legend_width, 1.6 + 3.3 * nrows),
                        dpi=120,
                        title=title, description="one panel per scene and resolution; "
                        "filled markers are Pareto-optimal for their case") as fig:
        axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True, sharex="col")
        for row, scene in enumerate(pc.scenes):
            for col, size in enumerate(pc.sizes):
                _pareto_panel(axes[row, col], pc, scene, size, color, markers)
                if row == nrows - 1:
                    axes[row, col].set_xlabel("warm time per call (ms, median)")
                if col == 0:
                    axes[row, col].set_ylabel("max |persp - reference|")
        _pareto_ticks(axes[-1])
        for ax in axes.flat[len(pc.scenes) * len(pc.sizes):]:
            ax.set_visible(False)
        _pareto_legend(fig, pc, color, markers, ncols)
        fig.suptitle(title)


def _pareto_panel(ax, pc: _ParetoCases, scene: str, size: tuple, color: dict,
                  markers: dict) -> None:
    """One scene at one resolution: a line per method through its cases, filled markers for
    the Pareto-optimal ones, the float32 / float64 rounding levels."""
    import math

    here = [c for c in pc.cases if c["scene"] == scene and tuple(c["resolution"]) == size]
    nonfinite = 0
    for method in pc.methods:
        pts = sorted((c for c in here if c["method"] == method), key=lambda c: c["triangles"])
        if not pts:
            continue
        x = [c["warm_ms"] for c in pts]
        y = [pc.shown(c) for c in pts]
        nonfinite += sum(not math.isfinite(c["error"]["persp"]["max"]) for c in pts)
        ax.plot(x, y, "-", color=color[method], lw=1.0, alpha=0.55, zorder=2)
        for c, xi, yi in zip(pts, x, y):
            ax.plot(xi, yi, markers[pc.count_key(c["triangles"])], ms=6.5, mew=1.3,
                    color=color[method], mfc=color[method] if pc.pareto_optimal(c) else "white",
                    zorder=3)
    for level, ls in ((EPS32, ":"), (EPS64, "-.")):
        if level > pc.lo:
            ax.axhline(level, color="0.35", lw=0.8, ls=ls, zorder=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(pc.lo, pc.hi)
    ax.grid(True, which="major", alpha=0.3)
    h, w = size
    res = f"{w}²" if w == h else f"{h}x{w} (HxW)"
    ax.set_title(f"{scene}, {res}" + (f" ({nonfinite} non-finite, at top)" if nonfinite else ""))
    ax.margins(x=0.12)


def _pareto_ticks(bottom_axes) -> None:
    """Plain tick labels; 1-2-5 ticks when a column spans less than 2 decades."""
    import math

    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    for ax in bottom_axes:
        x0, x1 = ax.get_xlim()
        subs = (1.0,) if math.log10(x1 / x0) > 2 else (1.0, 2.0, 5.0)
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())


def _pareto_legend(fig, pc: _ParetoCases, color: dict, markers: dict, ncols: int) -> None:
    """Three groups (methods, counts, what the lines and fills mean): below the panels,
    each group filling whole legend columns of 3 entries, or one column on the right of a
    narrow figure."""
    from matplotlib.lines import Line2D

    blank = Line2D([], [], ls="", label=" ")
    groups = [[Line2D([], [], color=color[m], marker="o", lw=1.0, label=m) for m in pc.methods],
              [Line2D([], [], color="0.3", marker=markers[n], ls="", mfc="0.3",
                      label=f"{_count_label(n)} triangle{'' if n == 1 else 's'}")
               for n in pc.counts],
              [Line2D([], [], color="0.3", marker="o", ls="", mfc="0.3",
                      label="Pareto-optimal for its case"),
               Line2D([], [], color="0.3", marker="o", ls="", mfc="white",
                      label="dominated: another method is faster and as accurate")]]
    groups[2] += [Line2D([], [], color="0.35", ls=ls, lw=0.8, label=label)
                  for level, ls, label in ((EPS32, ":", "$2^{-24}$ (float32 rounding)"),
                                           (EPS64, "-.", "$2^{-53}$ (float64 rounding)"))
                  if level > pc.lo]
    if (pc.errors == 0).any():
        groups[2].append(Line2D([], [], ls="", label=f"exact 0: drawn at {pc.zero_at:.0e}"))
    if ncols >= 3:
        rows = 3
        handles = []
        for g in groups:
            handles += g + [blank] * (-len(g) % rows)
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles) // rows,
                   frameon=False, columnspacing=1.6)
    else:
        handles = groups[0] + [blank] + groups[1] + [blank] + groups[2]
        fig.legend(handles=handles, loc="outside right center", frameon=False)
