"""The curves (through :mod:`glraster.io.figures`) and before/after pictures (through
:func:`glraster.io.png.write_png`) of the fits, for either front end: the pictures are
drawn by a *renderer* the front end passes (:class:`Renderer`).

Pictures are grids of panels, upright, separated by grey lines, each panel scaled to
``PANEL`` pixels with nearest-neighbour repetition (so 4 x 4 renders show their pixels):

- ``fit-cube-before-after.png``: a row per resolution (its first seed), columns: the target,
  the start and the result at the fit's resolution, then the same three at ``PANEL``
  pixels (true geometry and colours; the start; the fitted cube), for one fixed view;
- ``fit-pose-before-after.png``: a row per seed (the first ``POSE_ROWS``), the same columns
  (target rotation, the chosen restart's start, its result);
- ``fit-texture-before-after.png``: the true texture, the linear fit, the mipmapped fit
  (each started uniformly grey), one above the other, north pole up;
- ``fit-texture-views.png``: a row per held-out view (nearest and farthest of the first
  seed), columns: target, linear fit, mipmapped fit;
- ``fit-envmap-before-after.png``: a row per display view (``DISPLAY_QUATERNIONS``), columns:
  the true material, the start and the result of the first seed, at the fit's resolution
  (with a fitted cube map: under the grey start's and the fitted map).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Protocol

import numpy as np

from glraster.fitting import scenes
from glraster.io import figures
from glraster.io.atomic import staged_folder
from glraster.io.png import write_png

__all__ = ["PANEL", "Renderer", "cube_figures", "envmap_figures", "grid", "pose_figures",
           "scaled", "texture_figures", "upright", "write_grid"]

PANEL = 128
POSE_ROWS = 5
GAP = 4
GAP_RGB = 0.55


class Renderer(Protocol):
    """How a front end draws the fits' pictures (float32, no gradient); images are
    (N, R, R, 3) NumPy arrays, GL orientation (row 0 at the bottom)."""

    def cube(self, mvp: np.ndarray, vertices: np.ndarray, colors: np.ndarray, size: int, *,
             antialias: bool) -> np.ndarray:
        """The cube with ``vertices`` (8, 3) and ``colors`` (8, 3) under (N, 4, 4) ``mvp``."""

    def pose(self, quaternions: np.ndarray, size: int, *, antialias: bool) -> np.ndarray:
        """The cube turned by each of the (N, 4) ``quaternions`` (the pose fit's camera)."""

    def texture(self, mvp: np.ndarray, tex: np.ndarray, size: int, *, mip: bool) -> np.ndarray:
        """The sphere of the texture fit carrying ``tex`` (Ht, Wt, 3) under (N, 4, 4)
        ``mvp`` (linear-mipmap-linear when ``mip``, else linear)."""

    def envmap(self, quaternions: np.ndarray, material: dict, size: int, *, mesh: tuple,
               env_size: int, env: np.ndarray | None = None) -> np.ndarray:
        """The envmap fit's blob (``mesh`` (nu, nv)) turned by each of the (N, 4)
        ``quaternions`` with ``material`` ({"diffuse": (3,), "specular": (3,), "exponent"})
        under the studio cube map of ``env_size``² faces (or ``env`` (6, N, N, 3))."""


def upright(img) -> np.ndarray:
    """A GL-orientation (row 0 at the bottom) image as an upright float array."""
    return np.asarray(img, np.float64)[::-1]


def scaled(img: np.ndarray, height: int) -> np.ndarray:
    k = max(1, height // img.shape[0])
    return np.repeat(np.repeat(img, k, axis=0), k, axis=1)


def grid(rows) -> np.ndarray:
    """One upright image of rows of upright (h, w, 3) panels: each row as tall as its
    tallest panel (shorter ones padded at the bottom), rows left-aligned, GAP pixels of grey
    between and around panels."""
    rows = [list(r) for r in rows]
    heights = [max(p.shape[0] for p in r) for r in rows]
    widths = [sum(p.shape[1] for p in r) + GAP * (len(r) + 1) for r in rows]
    out = np.full((sum(heights) + GAP * (len(rows) + 1), max(widths), 3), GAP_RGB)
    y = GAP
    for r, h in zip(rows, heights):
        x = GAP
        for p in r:
            out[y:y + p.shape[0], x:x + p.shape[1]] = np.clip(p[..., :3], 0.0, 1.0)
            x += p.shape[1] + GAP
        y += h + GAP
    return out


def write_grid(path, rows, title):
    return write_png(path, grid(rows), bottom_up=False,
                     metadata={"Title": title, "Software": "glraster fit"})


def _one_set(write):
    """``write(fits, renderer, out_dir, ...)`` writing its files as one set
    (:func:`glraster.io.atomic.staged_folder`): a run whose figures fail leaves the last
    run's whole, not a mix of the two."""
    @functools.wraps(write)
    def written(fits, renderer, out_dir, **kwargs) -> list[Path]:
        with staged_folder(out_dir) as stage:
            paths = write(fits, renderer, stage, **kwargs)
        return [Path(out_dir) / Path(p).name for p in paths]
    return written


def _log_floor(values, floor):
    return np.maximum(np.asarray(values, np.float64), floor)


# --------------------------------------------------------------------------- cube


@_one_set
def cube_figures(fits, renderer: Renderer, out_dir) -> list[Path]:
    """Write fit-cube-error.png and fit-cube-before-after.png for a list of
    :class:`~glraster.fitting.results.CubeFit`; returns the paths."""
    out_dir = Path(out_dir)
    resolutions = sorted({f.resolution for f in fits})
    paths = []
    with figures.figure(out_dir / "fit-cube-error.png", figsize=(3.3 * len(resolutions), 3.4),
                        title="glraster fit cube: vertex error",
                        description="mean distance of the 8 vertices from the true ones "
                                    "per iteration, every seed") as fig:
        axes = np.atleast_1d(fig.subplots(1, len(resolutions), sharey=True, squeeze=False)[0])
        for ax, res in zip(axes, resolutions):
            runs = [f for f in fits if f.resolution == res]
            col = figures.colors([f.seed for f in runs])
            for f in runs:
                ax.semilogy(_log_floor(f.error, 1e-6), color=col[f.seed], lw=1.0,
                            label=f"seed {f.seed}: {f.error[-1]:.4f}")
            ax.axhline(0.05, color="k", ls="--", lw=0.8)
            aa = "antialias" if runs[0].antialias else "no antialias"
            ax.set_title(f"{res}x{res} px, {runs[0].views} views/it, {aa}")
            ax.set_xlabel("iteration")
            ax.grid(True, which="both")
            ax.legend(loc="upper right", title="final error")
        axes[0].set_ylabel("mean vertex error (cube side 1)")
    paths.append(out_dir / "fit-cube-error.png")

    mvp = scenes.view_matrices(scenes.quaternion_matrices(scenes.DISPLAY_QUATERNIONS[:1]),
                               distance=scenes.DISTANCE, fovy=scenes.FOVY)
    rows = []
    for res in resolutions:
        f = next(f for f in fits if f.resolution == res)
        states = [(f.true_pos, f.true_col), (f.start_pos, f.start_col),
                  (f.final_pos, f.final_col)]
        small, large = [], []
        for p, c in states:
            for size, dest in ((res, small), (PANEL, large)):
                img = renderer.cube(mvp, p, c, size, antialias=f.antialias)
                dest.append(scaled(upright(img[0]), PANEL))
        rows.append(small + large)
    paths.append(write_grid(out_dir / "fit-cube-before-after.png", rows,
                        "glraster fit cube: target, start, result"))
    return paths


# --------------------------------------------------------------------------- pose


@_one_set
def pose_figures(fits, renderer: Renderer, out_dir) -> list[Path]:
    """Write fit-pose-error.png and fit-pose-before-after.png for a list of
    :class:`~glraster.fitting.results.PoseFit`; returns the paths."""
    out_dir = Path(out_dir)
    paths = []
    first = fits[0]
    with figures.figure(out_dir / "fit-pose-error.png", figsize=(9.0, 3.6),
                        title="glraster fit pose: angle error",
                        description="rotation angle between the fitted and the true pose") as fig:
        ax1, ax2 = fig.subplots(1, 2, sharey=True)
        col = figures.colors(range(first.restarts))
        for r in range(first.restarts):
            ax1.semilogy(_log_floor(first.angle[:, r], 1e-5), color=col[r], lw=0.9,
                         label=f"restart {r}" + (" (chosen)" if r == first.best else ""))
        for it, _ in first.jumps:
            ax1.axvline(it, color="k", ls=":", lw=0.8)
        ax1.set_title(f"seed {first.seed}: every restart (dotted: symmetry jumps)")
        ax1.legend(loc="lower left", ncol=2, fontsize=7)
        col = figures.colors([f.seed for f in fits])
        for f in fits:
            # the restart with the lowest loss so far, as the fit would answer at each step
            losses = np.concatenate([f.loss, f.final_loss[None]])
            chosen = np.argmin(losses, axis=1)
            angle = f.angle[np.arange(len(chosen)), chosen]
            ax2.semilogy(_log_floor(angle, 1e-5), color=col[f.seed], lw=1.0,
                         label=f"seed {f.seed}: {f.best_angle:.2g} deg")
        ax2.set_title("the lowest-loss restart, every seed")
        ax2.legend(loc="upper right", title="final angle error")
        for ax in (ax1, ax2):
            ax.set_xlabel("iteration")
            ax.grid(True, which="both")
        ax1.set_ylabel("angle error (degrees; floor 1e-5)")
    paths.append(out_dir / "fit-pose-error.png")

    rows = []
    for f in fits[:POSE_ROWS]:
        qs = np.stack([f.target, f.start[f.best], f.final[f.best]])
        small = renderer.pose(qs, f.resolution, antialias=f.antialias)
        large = renderer.pose(qs, PANEL, antialias=f.antialias)
        rows.append([scaled(upright(i), PANEL) for i in small] + [upright(i) for i in large])
    paths.append(write_grid(out_dir / "fit-pose-before-after.png", rows,
                        "glraster fit pose: target, start, result"))
    return paths


# --------------------------------------------------------------------------- texture


@_one_set
def texture_figures(pairs, renderer: Renderer, out_dir, *, data) -> list[Path]:
    """Write fit-texture-psnr.png, fit-texture-before-after.png and fit-texture-views.png
    for a list of (linear TextureFit, mipmapped TextureFit) pairs, one per seed; ``data``:
    the first seed's (pool, held-out) views (``mvp``, ``target``, ``distance`` arrays)."""
    out_dir = Path(out_dir)
    paths = []
    with figures.figure(out_dir / "fit-texture-psnr.png", figsize=(9.0, 3.6),
                        title="glraster fit texture: PSNR",
                        description="held-out image PSNR and texture PSNR, linear against "
                                    "linear-mipmap-linear") as fig:
        ax1, ax2 = fig.subplots(1, 2)
        col = figures.colors(["linear", "linear-mipmap-linear"])
        for lin, mip in pairs:
            for f, name, ls in ((lin, "linear", "--"), (mip, "linear-mipmap-linear", "-")):
                ax1.plot(f.eval_iterations, f.eval_psnr, color=col[name], ls=ls, lw=1.0,
                         label=f"{name}, seed {f.seed}: {f.eval_psnr[-1]:.2f} dB")
                ax2.plot(f.eval_iterations, f.texture_psnr, color=col[name], ls=ls, lw=1.0,
                         label=f"{name}, seed {f.seed}: {f.texture_psnr[-1]:.2f} dB")
        ax1.set_title(f"held-out views ({pairs[0][0].resolution}² px, covered pixels)")
        ax2.set_title(f"texture ({2 * pairs[0][0].texture_size} x {pairs[0][0].texture_size}) "
                      f"against the truth")
        for ax in (ax1, ax2):
            ax.set_xlabel("iteration")
            ax.set_ylabel("PSNR (dB)")
            ax.grid(True)
            ax.legend(loc="lower right", fontsize=7)
    paths.append(out_dir / "fit-texture-psnr.png")

    lin, mip = pairs[0]
    truth = scenes.procedural_texture(lin.texture_size)
    paths.append(write_grid(out_dir / "fit-texture-before-after.png",
                        [[upright(truth)], [upright(lin.final)], [upright(mip.final)]],
                        "glraster fit texture: truth, linear fit, mipmapped fit"))
    held_out = data[1]
    order = np.argsort(held_out.distance)
    rows = []
    for k in (order[0], order[-1]):
        mvp = np.asarray(held_out.mvp[k:k + 1])
        row = [scaled(upright(np.asarray(held_out.target[k])), 2 * lin.resolution)]
        for f in (lin, mip):
            img = renderer.texture(mvp, f.final, f.resolution, mip=f.mip)
            row.append(scaled(upright(img[0]), 2 * lin.resolution))
        rows.append(row)
    paths.append(write_grid(out_dir / "fit-texture-views.png", rows,
                        "glraster fit texture: target, linear fit, mipmapped fit"))
    return paths


# --------------------------------------------------------------------------- envmap


@_one_set
def envmap_figures(fits, renderer: Renderer, out_dir) -> list[Path]:
    """Write fit-envmap-error.png (image RMSE, colour and exponent error per iteration,
    every seed) and fit-envmap-before-after.png (first seed) for a list of
    :class:`~glraster.fitting.results.EnvmapFit`; returns the paths."""
    out_dir = Path(out_dir)
    paths = []
    with figures.figure(out_dir / "fit-envmap-error.png", figsize=(11.0, 3.5),
                        title="glraster fit envmap: errors",
                        description="image RMSE of each step's views, colour error and "
                                    "relative exponent error per iteration") as fig:
        with_env = fits[0].fit_env
        axes = fig.subplots(1, 4 if with_env else 3)
        col = figures.colors([f.seed for f in fits])
        for f in fits:
            curves = (f.image_rmse, f.color_error, f.exponent_error) + (
                (f.env_rmse,) if with_env else ())
            for ax, curve in zip(axes, curves):
                ax.semilogy(_log_floor(curve, 1e-7), color=col[f.seed], lw=1.0,
                            label=f"seed {f.seed}: {curve[-1]:.2g}")
        first = fits[0]
        titles = (f"image RMSE ({first.resolution}² px, {first.views} views/it)",
                  "colour error (mean |c - c_true|, kd and ks)",
                  "exponent error |p - p_true| / p_true", "cube map texel RMSE")
        for ax, title in zip(axes, titles):
            ax.set_title(title, fontsize=9)
            ax.set_xlabel("iteration")
            ax.grid(True, which="both")
            ax.legend(loc="upper right", fontsize=7, title="final")
    paths.append(out_dir / "fit-envmap-error.png")

    f = fits[0]
    rows = []
    grey = None if f.final_env is None else np.full_like(f.final_env, 0.3)
    for q in scenes.DISPLAY_QUATERNIONS:
        row = []
        for material, env in ((f.true, None), (f.start, grey), (f.final, f.final_env)):
            img = renderer.envmap(q[None], material, f.resolution, mesh=f.mesh,
                                  env_size=f.env_size, env=env)
            row.append(scaled(upright(img[0]), max(PANEL, f.resolution)))
        rows.append(row)
    paths.append(write_grid(out_dir / "fit-envmap-before-after.png", rows,
                            "glraster fit envmap: target, start, result"))
    return paths
