"""Run time of the differentiable ops: derivatives, backward passes, determinism, and
interpolation against the same math in plain PyTorch.

A *cell* is (resolution, triangle count) on the benchmark terrain
(:func:`glraster.studies.bench.make_bench_scene`). For each cell, on one context, two sets
of calls are timed in interleaved rounds (A B C ... A B C ..., one warm-up round first;
every ratio is the median, min and max of its per-round ratios, so slow phases of a
shared machine hit both sides; wall time by ``time.perf_counter`` and CPU time of the
whole process, llvmpipe's and torch's threads included, by ``time.process_time``):

rasterize (the GPU core, :mod:`glraster.diff.rasterize`, on checked inputs)
    ``forward`` without and with ``rast_db`` (``grad_db=False`` / ``True``), and
    ``backward`` from random upstream gradients of rast and rast_db, with float
    atomics (the default) and ``deterministic=True``:
    ``db_over_nodb``, ``backward_atomic_over_forward``,
    ``backward_deterministic_over_forward`` (both against the forward with rast_db) and
    ``rasterize_deterministic_over_atomic``.
interpolate (A float32 attributes, ``diff_attrs="all"``)
    forward + backward of :func:`glraster.torch.interpolate` and of
    :func:`glraster.studies.torch_interpolate_baseline.interpolate` (gather + autograd) on
    the same leaf tensors (attr, rast, rast_db all requiring grad; the same random upstream
    gradients), each call's forward also timed on its own; the baseline twice, with
    torch's intra-op threads as set and with one thread (on cores shared with other work, OpenMP's
    spinning threads can make two threads several times slower than one), and each round
    compares glraster with the faster of the two; and the NumPy core's
    :func:`glraster.diff.interpolate.backward` with atomics and deterministic:
    ``glraster_over_baseline`` (< 1: glraster faster), ``interpolate_deterministic_over_atomic``.

Each cell also records ``same_math``: whether the baseline's out and out_da equal
glraster's bit for bit, and the largest difference of the gradients relative to the
largest entry (float32 sums in a different order). :func:`profile` splits one cell's calls
into phases with cProfile (upload, draw, readback, dispatch, host setup and reduction).
"""

from __future__ import annotations

import cProfile
import os
import pstats
import time

import numpy as np

from glraster.gpu.context import Context
from glraster.studies.bench import make_bench_scene

PRESETS = {
    "quick": {"resolutions": (256, 1024), "counts": (1000, 20000), "repeats": 7,
              "attributes": 4, "profile": None},
    "full": {"resolutions": (256, 512, 1024), "counts": (1000, 20000, 100000), "repeats": 15,
             "attributes": 4, "profile": ((1024, 1000), (1024, 20000))},
}

# ratio name -> (goal, comparison, resolutions it applies to (None: all))
GOALS = {
    "db_over_nodb": (1.3, "<=", None),
    "backward_atomic_over_forward": (2.0, "<=", None),
    "backward_deterministic_over_forward": (2.0, "<=", None),
    "glraster_over_baseline": (1.0, "<", (512, 1024)),
}

RASTER_CALLS = ("forward", "forward_db", "backward_atomic", "backward_deterministic")
INTERP_CALLS = ("glraster", "baseline", "baseline_1_thread", "core_backward_atomic",
                "core_backward_deterministic")


def _timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    inner = fn()
    return time.perf_counter() - wall, time.process_time() - cpu, inner


def round_robin(fns: dict, repeats: int) -> dict:
    """Call ``fns`` (name -> callable) in turn, ``repeats`` rounds after one warm-up round.
    A callable may return a dict of its own phase times in seconds (e.g. {"forward": s}).
    Returns name -> {"wall": (repeats,) s, "cpu": (repeats,) s, phase: (repeats,) s}."""
    for fn in fns.values():
        fn()
    times = {name: {"wall": [], "cpu": []} for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            wall, cpu, phases = _timed(fn)
            times[name]["wall"].append(wall)
            times[name]["cpu"].append(cpu)
            for phase, seconds in (phases if isinstance(phases, dict) else {}).items():
                times[name].setdefault(phase, []).append(seconds)
    return {name: {k: np.array(v) for k, v in t.items()} for name, t in times.items()}


def _time_stats(t: dict) -> dict:
    out = {"median_ms": float(np.median(t["wall"]) * 1e3), "min_ms": float(t["wall"].min() * 1e3),
           "max_ms": float(t["wall"].max() * 1e3),
           "cpu_median_ms": float(np.median(t["cpu"]) * 1e3)}
    for phase, v in t.items():
        if phase not in ("wall", "cpu"):
            out[f"{phase}_median_ms"] = float(np.median(v) * 1e3)
    return out


def _ratio(a: dict, b: dict) -> dict:
    """Per-round ratios a / b: wall median, min, max, and the median of the CPU ratios."""
    wall = a["wall"] / b["wall"]
    cpu = a["cpu"] / np.maximum(b["cpu"], 1e-9)
    return {"median": float(np.median(wall)), "min": float(wall.min()),
            "max": float(wall.max()), "cpu_median": float(np.median(cpu)),
            "pairs": int(len(wall))}


def _faster(a: dict, b: dict) -> dict:
    """Per round, the faster of two calls (wall and CPU time of the same one)."""
    pick = a["wall"] <= b["wall"]
    return {"wall": np.where(pick, a["wall"], b["wall"]), "cpu": np.where(pick, a["cpu"], b["cpu"])}


def _goal(name: str, ratio: float, size: int):
    goal, op, sizes = GOALS[name]
    if sizes is not None and size not in sizes:
        return None
    met = ratio <= goal if op == "<=" else ratio < goal
    return {"goal": f"{op} {goal}", "met": bool(met)}


class _Cell:
    """The inputs and calls of one cell (everything built outside the timed parts)."""

    def __init__(self, ctx, count: int, size: int, attributes: int, seed: int = 0):
        import glraster.torch as dr
        from glraster.diff import interpolate as core_interpolate
        from glraster.diff import rasterize as core_rasterize
        from glraster.diff.ops import INTERPOLATE, RASTERIZE
        from glraster.studies import torch_interpolate_baseline as baseline

        self.ctx, self.size = ctx, size
        self.resolution = (size, size)
        scene = make_bench_scene("terrain", count)
        self.pos, self.tri = scene.pos, scene.faces
        rng = np.random.default_rng(seed)
        (pos,), params = RASTERIZE.check(self.pos, tri=self.tri, resolution=self.resolution,
                                         ctx=ctx)
        (rast, rast_db), saved = core_rasterize.forward(pos, **params)
        self.rast, self.rast_db = rast, rast_db
        self.covered = float((rast[..., 3] != 0).mean())
        grad_rast = rng.standard_normal(rast.shape).astype(np.float32)
        grad_db = rng.standard_normal(rast.shape).astype(np.float32)
        attr = rng.standard_normal((len(self.pos), attributes)).astype(np.float32)
        g_out = rng.standard_normal(rast.shape[:3] + (attributes,)).astype(np.float32)
        g_da = rng.standard_normal(rast.shape[:3] + (2 * attributes,)).astype(np.float32)

        no_db = dict(params, grad_db=False)
        self.raster_calls = {
            "forward": lambda: core_rasterize.forward(pos, **no_db),
            "forward_db": lambda: core_rasterize.forward(pos, **params),
            "backward_atomic": lambda: core_rasterize.backward(saved, grad_rast, grad_db),
            "backward_deterministic": lambda: core_rasterize.backward(
                saved, grad_rast, grad_db, deterministic=True),
        }

        runner = baseline.ForwardBackward(attr, rast, self.tri, rast_db, g_out, g_da,
                                          diff_attrs="all",
                                          glctx=dr.RasterizeGLContext(context=ctx))
        self.runner = runner
        _, isaved = INTERPOLATE.forward(attr, rast, rast_db, tri=self.tri, diff_attrs="all",
                                        ctx=ctx)
        self.interp_calls = {
            "glraster": lambda: runner("glraster"),
            "baseline": lambda: runner("baseline"),
            "baseline_1_thread": lambda: runner("baseline", threads=1),
            "core_backward_atomic": lambda: core_interpolate.backward(isaved, g_out, g_da),
            "core_backward_deterministic": lambda: core_interpolate.backward(
                isaved, g_out, g_da, deterministic=True),
        }

    def same_math(self) -> dict:
        """Baseline against glraster on this cell's inputs: bit equality of out and out_da,
        and max |difference| / max |entry| of each gradient."""
        g = self.runner.outputs("glraster")
        b = self.runner.outputs("baseline")
        result = {"out_equal": bool(np.array_equal(g["out"], b["out"])),
                  "out_da_equal": bool(np.array_equal(g["out_da"], b["out_da"]))}
        for name in ("grad_attr", "grad_rast", "grad_rast_db"):
            scale = float(np.abs(b[name]).max())
            diff = float(np.abs(g[name] - b[name]).max())
            result[f"{name}_rel_diff"] = diff / scale if scale else diff
        return result


def run_cell(ctx, size: int, count: int, *, repeats: int = 5, attributes: int = 4) -> dict:
    """One (resolution, triangle count) cell: times, ratios, goals and same_math."""
    cell = _Cell(ctx, count, size, attributes)
    same = cell.same_math()
    raster = round_robin(cell.raster_calls, repeats)
    interp = round_robin(cell.interp_calls, repeats)
    ratios = {
        "db_over_nodb": _ratio(raster["forward_db"], raster["forward"]),
        "backward_atomic_over_forward": _ratio(raster["backward_atomic"], raster["forward_db"]),
        "backward_deterministic_over_forward": _ratio(raster["backward_deterministic"],
                                                      raster["forward_db"]),
        "rasterize_deterministic_over_atomic": _ratio(raster["backward_deterministic"],
                                                      raster["backward_atomic"]),
        "glraster_over_baseline": _ratio(interp["glraster"], _faster(interp["baseline"],
                                                                     interp["baseline_1_thread"])),
        "interpolate_deterministic_over_atomic": _ratio(interp["core_backward_deterministic"],
                                                        interp["core_backward_atomic"]),
    }
    goals = {name: g for name in GOALS
             if (g := _goal(name, ratios[name]["median"], size)) is not None}
    from glraster.diff import compute

    return {
        "resolution": [size, size], "triangles": int(len(cell.tri)), "attributes": attributes,
        "covered_fraction": cell.covered,
        "accumulation": compute.accumulation(ctx),
        "times": {**{f"rasterize_{k}": _time_stats(raster[k]) for k in RASTER_CALLS},
                  **{f"interpolate_{k}": _time_stats(interp[k]) for k in INTERP_CALLS}},
        "ratios": ratios, "goals": goals, "same_math": same,
    }


# --------------------------------------------------------------------------- profile

# phase -> (file suffix, function name) pairs whose cumulative time it is
PHASES = {
    "upload (buffer writes)": [("moderngl/__init__.py", "write")],
    "clear (framebuffer, zeroed buffers)": [("moderngl/__init__.py", "clear")],
    "draw call (binning)": [("moderngl/__init__.py", "render")],
    "compute dispatch + barrier": [("moderngl/__init__.py", "run"),
                                   ("moderngl/__init__.py", "memory_barrier")],
    "readback (framebuffer reads include the shading)": [("moderngl/__init__.py", "read_into"),
                                                  ("moderngl/__init__.py", "read")],
    "host setup records": [("glraster/diff/rasterize.py", "setup_records")],
    "host culling": [("glraster/gpu/cull.py", "cull")],
    "host reduction (ids; fixed-point decode)": [
        ("glraster/diff/compute.py", "corner_vertices"),
        ("glraster/diff/compute.py", "_decode")],
}


def _phases(fn, calls: int) -> dict:
    """Milliseconds per call of each PHASES entry (cumulative times, cProfile) and the rest."""
    fn()
    profiler = cProfile.Profile()
    wall = time.perf_counter()
    profiler.enable()
    for _ in range(calls):
        fn()
    profiler.disable()
    wall = time.perf_counter() - wall
    stats = pstats.Stats(profiler).stats
    out, covered = {}, 0.0
    for phase, keys in PHASES.items():
        seconds = sum(st[3] for (path, _, name), st in stats.items()
                      if any(path.replace(os.sep, "/").endswith(suffix) and name == func
                             for suffix, func in keys))
        if seconds > 0:
            out[phase] = seconds / calls * 1e3
            covered += seconds
    out["rest (Python, validation, NumPy, torch ops)"] = max(wall - covered, 0.0) / calls * 1e3
    out["total"] = wall / calls * 1e3
    return out


def profile(ctx, size: int, count: int, *, calls: int = 5, attributes: int = 4) -> dict:
    """Where each timed call of a cell spends its time (ms per call, cProfile: the phases
    of PHASES and the rest; the profiler itself adds a little to "rest")."""
    cell = _Cell(ctx, count, size, attributes)
    calls_ = {f"rasterize_{k}": fn for k, fn in cell.raster_calls.items()}
    calls_.update({f"interpolate_{k}": fn for k, fn in cell.interp_calls.items()})
    return {"resolution": [size, size], "triangles": int(len(cell.tri)),
            "ms_per_call": {name: _phases(fn, calls) for name, fn in calls_.items()}}


# --------------------------------------------------------------------------- the run


def run(preset: str = "quick", *, backend: str = "egl", progress=None, **overrides) -> dict:
    """Run a preset (PRESETS; keyword arguments override its fields: resolutions, counts,
    repeats, attributes, profile = a sequence of (size, count) cells or None).

    Returns {"settings", "machine", "cells": [run_cell dicts], "goals": {name: {"met": n,
    "cells": n}}, "profile": [profile() per cell], "seconds"}.
    ``progress(i, n, label)`` is called before each step.
    """
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    unknown = set(overrides) - set(PRESETS[preset])
    if unknown:
        raise ValueError(f"unknown settings {sorted(unknown)}; choose from "
                         f"{sorted(PRESETS[preset])}")
    settings = dict(PRESETS[preset], **overrides)
    from glraster.studies import torch_interpolate_baseline as baseline

    grid = [(s, c) for s in settings["resolutions"] for c in settings["counts"]]
    profiled = [tuple(p) for p in settings["profile"] or ()]
    steps = len(grid) + len(profiled)
    start = time.perf_counter()
    load_start = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    ctx = Context(backend)
    try:
        from glraster.diff import compute

        machine = {"renderer": ctx.renderer, "gl_version": ctx.gl_version,
                   "backend": ctx.backend, "cpus": os.cpu_count(),
                   **baseline.runtime(),
                   "accumulation": compute.accumulation(ctx)}
        cells = []
        for i, (size, count) in enumerate(grid):
            if progress:
                progress(i + 1, steps, f"{size}x{size}, {count} triangles")
            cells.append(run_cell(ctx, size, count, repeats=settings["repeats"],
                                  attributes=settings["attributes"]))
        prof = []
        for i, (size, count) in enumerate(profiled):
            if progress:
                progress(len(grid) + i + 1, steps, f"profile {size}x{size}, {count} triangles")
            prof.append(profile(ctx, size, count, attributes=settings["attributes"]))
    finally:
        ctx.release()
    machine["load_average"] = [load_start,
                               os.getloadavg()[0] if hasattr(os, "getloadavg") else None]
    goals = {}
    for cell in cells:
        for name, g in cell["goals"].items():
            goals.setdefault(name, []).append(g["met"])
    settings["profile"] = [list(p) for p in profiled]
    return {"settings": {"preset": preset, **{k: list(v) if isinstance(v, tuple) else v
                                              for k, v in settings.items()}},
            "machine": machine, "cells": cells,
            "goals": {name: {"met": sum(v), "cells": len(v)} for name, v in goals.items()},
            "profile": prof, "seconds": time.perf_counter() - start}


def table(result: dict) -> str:
    """The cells as a Markdown table (wall medians of per-round ratios; ms are medians)."""
    head = ("| frame | triangles | forward ms (no db / db) | db / no db | backward ms (atomic / "
            "det.) | bwd / fwd (atomic / det.) | det. / atomic, rasterize | interpolate fwd+bwd "
            "ms (glraster / PyTorch, its threads / 1 thread) | glraster / PyTorch | det. / "
            "atomic, interpolate |")
    lines = [head, "|" + "---|" * 10]
    for c in result["cells"]:
        t, r = c["times"], c["ratios"]
        lines.append(
            f"| {c['resolution'][0]}² | {c['triangles']} "
            f"| {t['rasterize_forward']['median_ms']:.1f} / "
            f"{t['rasterize_forward_db']['median_ms']:.1f} "
            f"| {r['db_over_nodb']['median']:.2f} "
            f"| {t['rasterize_backward_atomic']['median_ms']:.1f} / "
            f"{t['rasterize_backward_deterministic']['median_ms']:.1f} "
            f"| {r['backward_atomic_over_forward']['median']:.2f} / "
            f"{r['backward_deterministic_over_forward']['median']:.2f} "
            f"| {r['rasterize_deterministic_over_atomic']['median']:.2f} "
            f"| {t['interpolate_glraster']['median_ms']:.1f} / "
            f"{t['interpolate_baseline']['median_ms']:.1f}, "
            f"{t['interpolate_baseline_1_thread']['median_ms']:.1f} "
            f"| {r['glraster_over_baseline']['median']:.2f} "
            f"| {r['interpolate_deterministic_over_atomic']['median']:.2f} |")
    return "\n".join(lines)
