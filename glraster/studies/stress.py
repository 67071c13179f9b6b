"""Numerical stability sweeps: error of every method against an extended-precision truth.

Each sweep varies one parameter of a small scene and renders it with every method:

=============  ===========================================================================
origin         a well-shaped triangle (every altitude >= 8 px, w 1 .. 2.5) at x = 0 .. 16k px
               from the framebuffer origin, in a 16384 x 64 strip (the viewport is the
               whole strip: the triangle really sits 16k px from where llvmpipe anchors
               its plane equations)
origin_y      the same along y, in a 64 x 16384 strip
origin_xy     the same along the diagonal, at (d, d) for d = 0 .. 9800 px, in a 10000 x 10000
               viewport: both coordinates large at once. (A 16384 x 16384 float target
               cannot be allocated on llvmpipe, which refuses textures over 1.5 GiB.)
origin_w1      the same with every w = 1 (the affine path: persp = screen)
w_ratio        w of the vertices in ratio 1 .. 1e6 (same window-space triangle)
aspect         a sliver of length ~16k px and aspect 1 .. 1e6, in a 16384 x 64 strip
size           triangles of 1e-3 .. 1e3 px around pixel centers (llvmpipe snaps below
               1/256 px to zero area: no fragment there, reported as 0 pixels)
near           one vertex approaches the eye: w = 1 .. 1e-6, just inside the near plane
extent         a triangle covering the viewport with vertices 1 .. 1e8 viewport sizes
               away (guard-band and frustum clipping)
scale          every clip coordinate multiplied by 1e-30 .. 1e30 (the same image)
=============  ===========================================================================

Truth: the barycentrics of the float32 input triangle, evaluated per pixel in
np.longdouble (64-bit mantissa on x86) relative to the nearest vertex in front of the eye
(see :func:`truth`), so the reference's own error (~1e-19 relative) is far below any
float32 or float64 result judged here. homogeneous64 returns float64 read back exactly, so
errors down to the float64 rounding (~1e-16) are visible.

Per sweep point and method: pixels judged, max |error| of persp and screen, and the
normalized error max err / (eps32 (1 + |grad b| d)) with |grad b| the barycentric's
gradient (per px) and d the distance (px) to the nearest vertex; NaN/Inf counts.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from glraster.geometry.window import window_to_clip
from glraster.gpu.rasterize import METHODS, rasterize
from glraster.io.atomic import write_text

EPS32 = float(np.finfo(np.float32).eps)
STRIP = (64, 16384)
SQUARE = (10000, 10000)  # about the largest square vec3 float32 target llvmpipe allocates
LARGE_PIXELS = 1 << 24     # points above this free their framebuffers after measuring


@dataclass
class Point:
    """One rendered configuration: clip positions (V, 4) float32, triangles (T, 3) int32,
    resolution (H, W)."""

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple


def _from_window(win, w, z, resolution):
    """Clip positions (N, 4) float32 from window x, y (N, 2) in px, w (N,), NDC z (N,)."""
    return window_to_clip(win, resolution, z_ndc=z, w=w).astype(np.float32)


def _well_shaped(center, size, rotation):
    """Window positions (3, 2) of an equilateral-ish triangle of circumradius ``size``."""
    angles = rotation + np.array([0.0, 2.1, 4.2])
    return np.asarray(center, float) + size * np.stack([np.cos(angles), np.sin(angles)], 1)


def sweep_points(name: str):
    """(parameter values, list of Point) of one sweep (see the module table)."""
    rng = np.random.default_rng(7)
    w3 = np.array([1.0, 2.5, 1.6])
    z3 = np.array([0.1, -0.3, 0.5])
    if name == "origin":
        values = np.array([0, 64, 256, 1024, 4096, 8192, 12288, 16000])
        pts = []
        for d in values:
            win = _well_shaped((d + 40.3, 31.7), 28.0, 0.3)
            pts.append(Point(_from_window(win, w3, z3, STRIP), np.array([[0, 1, 2]]), STRIP))
        return values, pts
    if name == "origin_y":
        values = np.array([0, 1024, 8192, 16000])
        res = (STRIP[1], STRIP[0])
        pts = []
        for d in values:
            win = _well_shaped((31.7, d + 40.3), 28.0, 1.1)
            pts.append(Point(_from_window(win, w3, z3, res), np.array([[0, 1, 2]]), res))
        return values, pts
    if name == "origin_xy":
        values = np.array([0, 2500, 5000, 7500, 9800])
        pts = []
        for d in values:
            win = _well_shaped((d + 40.3, d + 31.7), 28.0, 0.3)
            pts.append(Point(_from_window(win, w3, z3, SQUARE), np.array([[0, 1, 2]]), SQUARE))
        return values, pts
    if name == "origin_w1":
        values = np.array([0, 64, 256, 1024, 4096, 8192, 12288, 16000])
        pts = []
        for d in values:
            win = _well_shaped((d + 40.3, 31.7), 28.0, 0.3)
            pts.append(Point(_from_window(win, np.ones(3), z3, STRIP), np.array([[0, 1, 2]]),
                             STRIP))
        return values, pts
    if name == "w_ratio":
        values = np.array([1, 10, 100, 1e3, 1e4, 1e5, 1e6])
        res = (96, 96)
        win = _well_shaped((47.3, 48.1), 40.0, 0.2)
        return values, [Point(_from_window(win, np.array([1.0, r, np.sqrt(r)]), z3, res),
                              np.array([[0, 1, 2]]), res) for r in values]
    if name == "aspect":
        values = np.array([1, 10, 100, 1e3, 1e4, 1e5, 1e6])
        pts = []
        for a in values:
            length = 16000.0
            h = max(length / a, 1e-9)
            p0 = np.array([150.3, 20.2])
            direction = np.array([1.0, 24.0 / length])
            direction /= np.linalg.norm(direction)
            normal = np.array([-direction[1], direction[0]])
            win = np.stack([p0, p0 + length * direction, p0 + 0.37 * length * direction + h * normal])
            if a == 1:  # aspect 1: a fat triangle in the same strip
                win = _well_shaped((2000.3, 32.1), 30.0, 0.1)
            pts.append(Point(_from_window(win, w3, z3, STRIP), np.array([[0, 1, 2]]), STRIP))
        return values, pts
    if name == "size":
        values = np.array([1e-3, 1e-2, 1e-1, 1, 10, 100, 1000])
        res = (256, 256)
        pts = []
        for s in values:
            count = 200 if s < 50 else 1
            centers = np.stack([rng.integers(2, 254, count) + 0.5, rng.integers(2, 254, count) + 0.5], 1)
            if s >= 50:
                centers = np.array([[128.3, 127.9]])
            wins = np.concatenate([_well_shaped(c + rng.uniform(-0.2, 0.2, 2) * s, s, rng.uniform(0, 6))
                                   for c in centers])
            w = np.tile(w3, count)
            z = np.tile(z3, count)
            pts.append(Point(_from_window(wins, w, z, res),
                             np.arange(3 * count).reshape(count, 3), res))
        return values, pts
    if name == "near":
        values = np.array([1, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6])
        res = (96, 96)
        pts = []
        for wn in values:
            pos = np.array([[-0.7, -0.6, 0.2, 1.0], [0.8, -0.5, 0.0, 1.3],
                            [0.05 * wn, 0.1 * wn, -wn * (1 - 1e-3), wn]], np.float32)
            pts.append(Point(pos, np.array([[0, 1, 2]]), res))
        return values, pts
    if name == "extent":
        values = np.array([1, 10, 100, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8])
        res = (96, 96)
        pts = []
        for e in values:
            ndc = np.array([[-1.1 * e, -0.9 * e], [1.3 * e, -1.05 * e], [0.1 * e, 1.2 * e]])
            win = (ndc + 1) * np.array([res[1], res[0]]) / 2
            pts.append(Point(_from_window(win, w3, z3 * 0.5, res), np.array([[0, 1, 2]]), res))
        return values, pts
    if name == "scale":
        values = np.array([1e-30, 1e-20, 1e-10, 1, 1e10, 1e20, 1e30])
        res = (96, 96)
        win = _well_shaped((47.3, 48.1), 40.0, 0.2)
        base = _from_window(win, w3, z3, res).astype(np.float64)
        return values, [Point((base * s).astype(np.float32), np.array([[0, 1, 2]]), res)
                        for s in values]
    raise ValueError(f"sweep must be one of {SWEEPS}, got {name!r}")


SWEEPS = ("origin", "origin_y", "origin_xy", "origin_w1", "w_ratio", "aspect", "size", "near", "extent", "scale")


def truth(pos, tri, tri_id, resolution):
    """Extended-precision barycentrics at the pixels of ``tri_id`` (H, W) int32 >= 0.

    Returns (pix, persp, screen, grad_persp, grad_screen, d): pix (N,) flat pixel
    indices; persp, screen (N, 3) float64 (rounded from np.longdouble); grad_* (N, 3)
    |gradient| per px; d (N,) distance in px to the nearest vertex in front of the eye.

    With homogeneous window coordinates X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2, the
    edge functions satisfy e_i(col_j) = delta_ij det (adjugate identity), so relative to a
    vertex j:  w_j e_i(p) = A_i (p_x w_j - X_j) + B_i (p_y w_j - Y_j) + delta_ij det.
    """
    height, width = resolution
    L = np.longdouble
    pix = np.flatnonzero(tri_id.reshape(-1) >= 0)
    t = tri_id.reshape(-1)[pix]
    c = pos[tri[t]].astype(L)                      # (N, 3, 4)
    w = c[..., 3]
    X = (c[..., 0] + w) * L(width / 2)
    Y = (c[..., 1] + w) * L(height / 2)
    j, k = [1, 2, 0], [2, 0, 1]
    A = Y[:, j] * w[:, k] - Y[:, k] * w[:, j]
    B = w[:, j] * X[:, k] - w[:, k] * X[:, j]
    C = X[:, j] * Y[:, k] - X[:, k] * Y[:, j]
    det = (A[:, 0] * X[:, 0] + B[:, 0] * Y[:, 0] + C[:, 0] * w[:, 0])
    px = (pix % width).astype(L) + L(0.5)
    py = (pix // width).astype(L) + L(0.5)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        vx = np.where(w > 0, X / w, np.inf)
        vy = np.where(w > 0, Y / w, np.inf)
        dist = np.hypot((vx - px[:, None]).astype(np.float64), (vy - py[:, None]).astype(np.float64))
    m = np.argmin(np.nan_to_num(dist, nan=np.inf), 1)
    rows = np.arange(len(pix))
    wm, Xm, Ym = w[rows, m][:, None], X[rows, m][:, None], Y[rows, m][:, None]
    delta = np.arange(3)[None, :] == m[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e = (A * (px[:, None] * wm - Xm) + B * (py[:, None] * wm - Ym) + delta * det[:, None]) / wm
        total = e.sum(1, keepdims=True)
        persp = e / total
        screen = e * w / det[:, None]
        # gradients in float64 (only their size matters)
        gs = np.stack([A, B], -1).astype(np.float64) / det.astype(np.float64)[:, None, None]
        s = (e / det[:, None]).astype(np.float64)
        S = s.sum(1, keepdims=True)
        gS = gs.sum(1, keepdims=True)
        gp = (gs * S[..., None] - s[..., None] * gS) / (S[..., None] ** 2)
        grad_persp = np.hypot(gp[..., 0], gp[..., 1])
        gsc = gs * w.astype(np.float64)[..., None]
        grad_screen = np.hypot(gsc[..., 0], gsc[..., 1])
    d = dist[rows, m]
    return (pix, persp.astype(np.float64), screen.astype(np.float64), grad_persp,
            grad_screen, d)


def measure(point: Point, method: str, ctx) -> dict:
    """Error statistics of ``method`` on one point (see the module docstring). Only the
    covered pixels are kept; the framebuffers of large points are freed afterwards."""
    outputs = ("persp", "screen", "depth", "tri_id")
    r = rasterize(point.pos, point.tri, point.resolution, ctx=ctx, method=method,
                  outputs=outputs, cull=False)
    nonfinite = int(sum((~np.isfinite(getattr(r, n))).sum() for n in ("persp", "screen", "depth")))
    out = {"pixels": int(r.mask.sum()), "nonfinite": nonfinite}
    pix = np.flatnonzero(r.tri_id.reshape(-1) >= 0)   # the pixels truth() evaluates
    values = {name: getattr(r, name).reshape(-1, 3)[pix].astype(np.float64)
              for name in ("persp", "screen")}
    tri_id = r.tri_id
    del r
    if point.resolution[0] * point.resolution[1] > LARGE_PIXELS:
        ctx.release_targets()
    if not len(pix):
        return out
    _, persp, screen, g_persp, g_screen, d = truth(point.pos, point.tri, tri_id,
                                                   point.resolution)
    for name, ref, grad in (("persp", persp, g_persp), ("screen", screen, g_screen)):
        got = values[name]
        err = np.abs(got - ref)
        err = np.where(np.isfinite(err), err, np.inf)
        with np.errstate(invalid="ignore", over="ignore"):
            ratio = err / (EPS32 * (1 + grad * d[:, None]))
        out[name] = {"max": float(err.max()), "ratio_max": float(np.nanmax(ratio)),
                     "mean": float(err.mean())}
    out["grad_d_max"] = float(np.nanmax(g_persp * d[:, None]))
    return out


def run(sweeps=SWEEPS, methods=tuple(METHODS), *, ctx=None, progress=None) -> dict:
    """Every sweep x method. Returns {sweep: {"values": [...], "methods": {method: [point
    stats, ...]}}}. ``progress(i, n, label)`` is called before each point."""
    from glraster.gpu.context import default_context

    ctx = ctx or default_context()
    out = {}
    total = sum(len(sweep_points(s)[0]) for s in sweeps) * len(methods)
    i = 0
    for sweep in sweeps:
        values, points = sweep_points(sweep)
        out[sweep] = {"values": [float(v) for v in values], "methods": {}}
        for method in methods:
            stats = []
            for value, point in zip(values, points):
                i += 1
                if progress:
                    progress(i, total, f"{sweep} {method} {value:g}")
                stats.append(measure(point, method, ctx))
            out[sweep]["methods"][method] = stats
    return out


_AXIS_LABELS = {"origin": "x distance from the origin (px)",
                "origin_y": "y distance from the origin (px)",
                "origin_xy": "(d, d) from the origin: d (px)",
                "origin_w1": "x distance, every w = 1 (px)",
                "w_ratio": "w ratio of the vertices", "aspect": "sliver aspect ratio",
                "size": "triangle size (px)", "near": "w of the vertex near the eye",
                "extent": "vertex distance (viewport sizes)", "scale": "clip-coordinate scale"}


def plot(result: dict, path: str, columns: int = 5) -> None:
    """One PNG: per sweep two stacked panels, max |persp error| (top) and the normalized
    error err / (eps32 (1 + |grad b| d)) (bottom, dashed line at 16) per method against the
    swept parameter, log scales (linear x for the origin sweeps); sweeps wrap at
    ``columns`` per row. A black cross marks a point whose output held NaN/Inf (its error
    is over the finite pixels); a point without judged pixels is left out. Dotted lines:
    2^-24 and 2^-53. Written through :func:`glraster.io.figures.figure`."""
    import math

    from matplotlib.lines import Line2D

    from glraster.io import figures

    sweeps = list(result)
    ncols = max(1, min(columns, len(sweeps)))
    nblocks = math.ceil(len(sweeps) / ncols)
    methods = [m for m in METHODS if any(m in result[s]["methods"] for s in sweeps)]
    methods += sorted({m for s in sweeps for m in result[s]["methods"]} - set(methods))
    color = figures.colors(METHODS)
    color.update({m: figures.PALETTE[(len(METHODS) + i) % len(figures.PALETTE)]
                  for i, m in enumerate(m for m in methods if m not in color)})
    err_floor, ratio_floor = 1e-17, 1e-10
    eps32, eps64 = 2.0**-24, 2.0**-53
    title = "glraster stress sweeps on llvmpipe (persp barycentrics)"
    with figures.figure(path, figsize=(3.2 * ncols + 0.6, 5.2 * nblocks + 0.9), dpi=110,
                        title=title, description="max |persp error| and normalized error "
                        "per method against each swept parameter") as fig:
        axes = fig.subplots(2 * nblocks, ncols, squeeze=False)
        nonfinite_seen = False
        for k, sweep in enumerate(sweeps):
            block, col = divmod(k, ncols)
            top, bottom = axes[2 * block, col], axes[2 * block + 1, col]
            bottom.sharex(top)
            values = np.array(result[sweep]["values"], dtype=float)
            linear = sweep.startswith("origin")
            x = values if linear else np.where(values > 0, values, np.nan)  # no 0 on log x
            for method, stats in result[sweep]["methods"].items():
                err = np.array([s.get("persp", {}).get("max", np.nan) for s in stats])
                ratio = np.array([s.get("persp", {}).get("ratio_max", np.nan) for s in stats])
                bad = np.array([s.get("nonfinite", 0) > 0 for s in stats])
                err = np.clip(err, err_floor, 1e2)
                ratio = np.clip(ratio, ratio_floor, 1e14)
                for ax, y in ((top, err), (bottom, ratio)):
                    ax.plot(x, y, "o-", color=color[method], ms=3.5, lw=1.2)
                    if bad.any():
                        nonfinite_seen = True
                        ax.plot(x[bad], y[bad], "x", color="k", ms=6, mew=1.2, zorder=4)
            for level, ls in ((eps32, ":"), (eps64, "-.")):
                top.axhline(level, color="0.4", lw=0.8, ls=ls, zorder=1)
            bottom.axhline(16, color="k", lw=0.8, ls="--", zorder=1)
            for ax in (top, bottom):
                ax.set_yscale("log")
                if not linear:
                    ax.set_xscale("log")
                ax.grid(True, which="major", alpha=0.3)
            top.set_ylim(err_floor / 3, 3e2)
            top.set_title(sweep)
            top.tick_params(labelbottom=False)
            bottom.set_xlabel(_AXIS_LABELS.get(sweep, sweep))
            if col == 0:
                top.set_ylabel("max |persp error|")
                bottom.set_ylabel("err / (eps32 (1 + |grad b| d))")
        for k in range(len(sweeps), nblocks * ncols):
            block, col = divmod(k, ncols)
            axes[2 * block, col].set_visible(False)
            axes[2 * block + 1, col].set_visible(False)
        handles = [Line2D([], [], color=color[m], marker="o", ms=3.5, label=m) for m in methods]
        handles += [Line2D([], [], color="0.4", ls=":", lw=0.8, label="$2^{-24}$"),
                    Line2D([], [], color="0.4", ls="-.", lw=0.8, label="$2^{-53}$"),
                    Line2D([], [], color="k", ls="--", lw=0.8, label="normalized error 16")]
        if nonfinite_seen:
            handles.append(Line2D([], [], color="k", marker="x", ls="", label="NaN/Inf in output"))
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles),
                   frameon=False)
        fig.suptitle(title)


def write_json(result: dict, path: str) -> None:
    """Write ``result`` as JSON to ``path``, creating its folder; nothing partial is left."""
    write_text(path, json.dumps(result, indent=1))
