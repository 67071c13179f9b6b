"""`glraster fit`: inverse rendering: fit a cube, a pose, a texture or a material to images.

`glraster fit cube|pose|texture|envmap` recovers a scene made in code from images of it
through glraster.torch (rasterize, interpolate, antialias, texture), or glraster.jax with
`--framework jax` (docs/jax.md; not envmap): 'cube' fits the 8 vertex
positions and colours of a cube at a few pixels, 'pose' a cube's rotation, 'texture' a
texture on a sphere with and without mipmaps, 'envmap' a Phong material (diffuse and
specular colour, exponent) on a blob under a cube-map sky (docs/fitting.md). Each shows a
progress bar
on stderr, prints one line per run and the time per iteration (forward, backward,
optimizer step), and writes its curve and before/after PNGs into --out (and with --json
the numbers). Exit code 0 when the problem's goal is met (cube: most seeds of every
resolution under 0.05; pose: most seeds under 5 degrees; texture: mipmapping gives the
higher held-out PSNR for every seed; envmap: every seed's colour error under 0.01 and
relative exponent error under 0.05; with --fit-env, the cube map's texel RMSE halved), 1
when it is not, 2 on bad arguments, 3 without
OpenGL.
"""

from __future__ import annotations

import json
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command, positive_float
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFile, OutputFolder

CUBE_GOAL = 0.05    # mean vertex error
ENVMAP_COLOR_GOAL = 0.01     # mean |colour - true| over kd and ks
ENVMAP_EXPONENT_GOAL = 0.05  # |p - p_true| / p_true
FRAMEWORKS = ("torch", "jax")
POSE_GOAL = 5.0     # degrees


class Progress:
    """``(i, total, label)`` -> a one-line bar on stderr, redrawn at most every 0.2 s on a
    terminal; elsewhere a line at every 10 % (and at the end)."""

    def __init__(self, name: str, stream=None, width: int = 24):
        self.name = name
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.width = width
        self.t0 = self.last = time.perf_counter()
        self.decile = -1

    def __call__(self, i, total, label):
        now = time.perf_counter()
        done = i >= total
        if self.tty:
            if not done and now - self.last < 0.2:
                return
        else:
            decile = (10 * i) // max(total, 1)
            if decile == self.decile and not done:
                return
            self.decile = decile
        self.last = now
        filled = int(self.width * i / max(total, 1))
        rate = i / max(now - self.t0, 1e-9)
        text = (f"{self.name} [{'#' * filled}{'.' * (self.width - filled)}] {i}/{total} "
                f"{now - self.t0:5.1f}s {rate:5.1f} it/s {label}")
        if self.tty:
            self.stream.write("\r" + text[:118].ljust(118) + ("\n" if done else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


def _ints(text: str, name: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ArgumentError(f"--{name}", f"--{name} must be comma-separated integers, "
                                         f"got {text!r}") from None
    if not values or min(values) < 1:
        raise ArgumentError(f"--{name}", f"--{name} must be positive integers, got {text!r}")
    return values


def _positive(name: str, value: int) -> int:
    if value < 1:
        raise ArgumentError(f"--{name}", f"--{name} must be >= 1, got {value}")
    return value


def _seeds(args) -> list[int]:
    if args.first_seed < 0:
        raise ArgumentError("--first-seed", f"--first-seed must be >= 0, got {args.first_seed}")
    return list(range(args.first_seed, args.first_seed + _positive("seeds", args.seeds)))


def _no_antialias(q) -> None:
    q.add_argument("--no-antialias", action="store_true",
                   help="rasterize -> interpolate only (no visibility gradient)")


def _resolution(q, default: int) -> None:
    q.add_argument("--resolution", type=int, default=default,
                   help=f"image size in pixels ({default})")


def _views(q, default: int, what: str) -> None:
    q.add_argument("--views", type=int, default=default, help=f"{what} ({default})")


def register(subparsers) -> None:
    p = add_command(subparsers, "fit", __doc__)
    sub = p.add_subparsers(dest="problem", metavar="PROBLEM", required=True)

    def common(q, *, seeds, iterations, out_name):
        q.add_argument("--seeds", type=int, default=seeds, help=f"seeds per setting ({seeds})")
        q.add_argument("--first-seed", type=int, default=0, help="first seed (0)")
        q.add_argument("--iterations", type=int, default=iterations,
                       help=f"optimizer steps per run ({iterations})")
        q.add_argument("--out", action=OutputFolder, default=f"out/fit/{out_name}", metavar="DIR",
                       help=f"where the PNGs go (out/fit/{out_name})")
        q.add_argument("--json", action=OutputFile,
                       default=None, metavar="FILE", help="write the results as JSON")
        q.add_argument("--threads", type=int, default=1,
                       help="torch CPU threads (1: the tensors are small, and llvmpipe "
                            "needs the cores; torch only)")
        q.add_argument("--framework", choices=FRAMEWORKS, default="torch",
                       help="the front end the fit runs on: glraster.torch (default) or "
                            "glraster.jax")
        q.add_argument("--quiet", action="store_true", help="no progress bar")
        add_backend_argument(q)

    q = sub.add_parser("cube", help="fit a cube's vertex positions and colours",
                       description="Fit the 8 vertex positions and colours of a cube from a "
                                   "random start (mean vertex error ~0.5) by an image loss "
                                   "through rasterize -> interpolate -> antialias, several "
                                   "random views per iteration.")
    common(q, seeds=5, iterations=1000, out_name="cube")
    q.add_argument("--resolutions", default="4,8,16", help="image sizes in pixels (4,8,16)")
    _views(q, 4, "random views per iteration")
    q.add_argument("--lr", type=positive_float, default=1e-2,
                   help="Adam's learning rate (1e-2), falling to a tenth by the end")
    _no_antialias(q)
    q.set_defaults(func=_run_cube)

    q = sub.add_parser("pose", help="recover a cube's rotation from an image",
                       description="Recover a cube's rotation (quaternion) from one image "
                                   "with random restarts and jumps between the cube's "
                                   "symmetric poses.")
    common(q, seeds=5, iterations=300, out_name="pose")
    _resolution(q, 32)
    q.add_argument("--restarts", type=int, default=8, help="random starts per seed (8)")
    q.add_argument("--no-jumps", action="store_true",
                   help="gradient descent from the restarts only (no symmetry jumps)")
    _no_antialias(q)
    q.set_defaults(func=_run_pose)

    q = sub.add_parser("texture", help="recover a texture on a sphere, mipmapped and not",
                       description="Recover a procedural texture on a sphere from "
                                   "supersampled images, once with linear-mipmap-linear "
                                   "lookups (uv_da from interpolate) and once with linear "
                                   "ones; compares their PSNR.")
    common(q, seeds=1, iterations=1000, out_name="texture")
    _resolution(q, 128)
    q.add_argument("--texture-size", type=int, default=256,
                   help="texture height; the width is twice it (256)")
    _views(q, 4, "views per iteration")
    q.add_argument("--pool", type=int, default=64, help="training views (64)")
    q.add_argument("--eval-every", type=int, default=50,
                   help="iterations between held-out evaluations (50)")
    q.set_defaults(func=_run_texture)

    q = sub.add_parser("envmap", help="recover a Phong material under a cube-map sky",
                       description="Recover a Phong material (diffuse and specular colour, "
                                   "exponent) on a 30,720-triangle blob lit by a procedural "
                                   "cube map from a random start: rasterize with rast_db, "
                                   "interpolate with diff_attrs='all', two "
                                   "linear-mipmap-linear cube lookups with uv_da per pixel, "
                                   "two random views per iteration (torch only).")
    common(q, seeds=1, iterations=300, out_name="envmap")
    _resolution(q, 256)
    q.add_argument("--env-size", type=int, default=512,
                   help="cube map face size in texels (512)")
    q.add_argument("--mesh", default="128,120",
                   help="the blob's longitudes,latitudes: 2 x their product triangles "
                        "(128,120: 30,720)")
    _views(q, 2, "random views per iteration")
    q.add_argument("--lr", type=positive_float, default=0.06,
                   help="Adam's learning rate of the colours (0.06), falling to a tenth by "
                        "the end")
    q.add_argument("--exponent-lr", type=positive_float, default=0.15,
                   help="Adam's learning rate of the exponent's logarithm (0.15), falling to "
                        "a tenth by the end")
    q.add_argument("--fit-env", action="store_true",
                   help="fit the cube map instead, from a uniform grey start, under the "
                        "true material (goal: its texel RMSE halved)")
    q.add_argument("--env-lr", type=positive_float, default=0.06,
                   help="Adam's learning rate of the cube map's texels (0.06; --fit-env)")
    q.set_defaults(func=_run_envmap)


@contextmanager
def _session(args):
    """A RasterizeGLContext of ``--framework`` on a new context of ``--backend`` (torch:
    with ``--threads`` CPU threads; glraster.torch.fitting.common.session,
    glraster.jax.fitting.common.session)."""
    _positive("threads", args.threads)
    _positive("iterations", args.iterations)
    if args.framework == "jax":
        from glraster.jax.fitting.common import session

        with session(backend=args.backend) as glctx:
            yield glctx
        return
    from glraster.torch.fitting.common import session

    with session(backend=args.backend, threads=args.threads) as glctx:
        yield glctx


def _fitting(args, name):
    """The modules of fit ``name`` and its figures for ``--framework``."""
    import importlib

    package = f"glraster.{args.framework}.fitting"
    return (importlib.import_module(f"{package}.{name}"),
            importlib.import_module(f"{package}.figures"))


def _progress(args, name):
    return None if args.quiet else Progress(name)


def _timing_line(name, summaries) -> str:
    from glraster.fitting.scenes import Timer

    t = Timer.merge(summaries)
    parts = [f"{k} {t[k]['mean_ms']:.1f}" for k in ("target", "forward", "backward", "forward+backward", "step")
             if k in t]
    return f"{name}: ms per iteration (mean): " + ", ".join(parts)


def _finish(args, result, paths) -> None:
    if args.json:
        from glraster.io.atomic import atomic_write

        path = Path(args.json)
        with atomic_write(path, suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(result, indent=1) + "\n")
        paths = [*paths, path]
    print("wrote " + ", ".join(str(p) for p in paths))


def _run_cube(args) -> int:
    cube, figures = _fitting(args, "cube")
    resolutions = _ints(args.resolutions, "resolutions")
    _positive("views", args.views)
    seeds = _seeds(args)
    antialias = not args.no_antialias
    with _session(args) as glctx:
        fits = []
        for res in resolutions:
            for seed in seeds:
                f = cube.fit_cube(glctx, res, seed, iterations=args.iterations,
                                  views=args.views, lr=args.lr, antialias=antialias,
                                  progress=_progress(args, "cube"))
                fits.append(f)
                first = f.summary()["first_below_0.05"]
                when = (f"under {CUBE_GOAL} from iteration {first}" if first is not None
                        else f"never under {CUBE_GOAL}")
                loss_at = f.summary()["first_loss_below_0.01"]
                print(f"cube {res}x{res} seed {seed}: error {f.error[0]:.3f} -> "
                      f"{f.error[-1]:.3g} (colour {f.color_error[-1]:.3g}), {when}; image "
                      f"loss {f.loss[0]:.3g} -> {f.loss[-1]:.3g}"
                      + (f", under 0.01 from iteration {loss_at}" if loss_at is not None
                         else ""), flush=True)
        paths = figures.cube_figures(fits, glctx, args.out)
    met = True
    per_res = {}
    for res in resolutions:
        runs = [f for f in fits if f.resolution == res]
        below = sum(f.error[-1] < CUBE_GOAL for f in runs)
        met &= below > len(runs) / 2
        per_res[res] = below
        print(f"{res}x{res}: {below}/{len(runs)} seeds under {CUBE_GOAL}; "
              + _timing_line("time", [f.timing for f in runs]))
    print(f"goal (most seeds of every resolution under {CUBE_GOAL}): "
          f"{'met' if met else 'MISSED'}")
    _finish(args, {"problem": "cube", "framework": args.framework, "goal_met": bool(met),
                   "runs": [f.summary() for f in fits]}, paths)
    return exit_codes.OK if met else exit_codes.FAIL


def _run_pose(args) -> int:
    pose, figures = _fitting(args, "pose")
    _positive("resolution", args.resolution)
    _positive("restarts", args.restarts)
    antialias = not args.no_antialias
    with _session(args) as glctx:
        fits = []
        for seed in _seeds(args):
            f = pose.fit_pose(glctx, seed, resolution=args.resolution, restarts=args.restarts,
                              iterations=args.iterations,
                              jumps=() if args.no_jumps else (0.25, 0.5),
                              antialias=antialias, progress=_progress(args, "pose"))
            fits.append(f)
            s = f.summary()
            print(f"pose seed {seed}: angle error {f.best_angle:.3g} deg (restart {f.best}, "
                  f"from {s['start_angle_deg_of_best']:.1f}); {s['restarts_within_5deg']}/"
                  f"{f.restarts} restarts within 5 deg", flush=True)
        paths = figures.pose_figures(fits, glctx, args.out)
    below = sum(f.best_angle < POSE_GOAL for f in fits)
    met = below > len(fits) / 2
    print(f"{below}/{len(fits)} seeds under {POSE_GOAL} deg; "
          + _timing_line("time", [f.timing for f in fits]))
    print(f"goal (most seeds under {POSE_GOAL} deg): {'met' if met else 'MISSED'}")
    _finish(args, {"problem": "pose", "framework": args.framework, "goal_met": bool(met),
                   "runs": [f.summary() for f in fits]}, paths)
    return exit_codes.OK if met else exit_codes.FAIL


def _run_texture(args) -> int:
    texture, figures = _fitting(args, "texture")
    for name in ("resolution", "texture_size", "views", "pool", "eval_every"):
        _positive(name.replace("_", "-"), getattr(args, name))
    if args.views > args.pool:
        raise ArgumentError(
            "--views", f"--views ({args.views}) must not exceed --pool ({args.pool})")
    with _session(args) as glctx:
        pairs, first_data = [], None
        for seed in _seeds(args):
            data = texture.make_data(glctx, seed, resolution=args.resolution,
                                     texture_size=args.texture_size, pool=args.pool)
            first_data = first_data or data
            pair = []
            for mip in (False, True):
                f = texture.fit_texture(glctx, seed, mip=mip, resolution=args.resolution,
                                        texture_size=args.texture_size,
                                        iterations=args.iterations, views=args.views,
                                        eval_every=args.eval_every, data=data,
                                        progress=_progress(args, "texture"))
                pair.append(f)
                print(f"texture seed {seed} {f.summary()['filter_mode']}: held-out PSNR "
                      f"{f.eval_psnr[-1]:.2f} dB, texture PSNR {f.texture_psnr[-1]:.2f} dB",
                      flush=True)
            pairs.append(tuple(pair))
        paths = figures.texture_figures(pairs, glctx, args.out, data=first_data)
    met = all(mip.eval_psnr[-1] > lin.eval_psnr[-1] for lin, mip in pairs)
    for k, name in enumerate(("linear", "linear-mipmap-linear")):
        print(_timing_line(name, [p[k].timing for p in pairs]))
    print(f"goal (mipmapped PSNR above linear for every seed): {'met' if met else 'MISSED'}")
    _finish(args, {"problem": "texture", "framework": args.framework, "goal_met": bool(met),
                   "runs": [f.summary() for p in pairs for f in p]}, paths)
    return exit_codes.OK if met else exit_codes.FAIL


def _run_envmap(args) -> int:
    if args.framework != "torch":
        raise ArgumentError("--framework", "glraster fit envmap runs on glraster.torch only "
                                           f"(--framework torch), got {args.framework!r}")
    envmap, figures = _fitting(args, "envmap")
    for name in ("resolution", "views"):
        _positive(name, getattr(args, name))
    if args.env_size < 2:
        raise ArgumentError("--env-size", f"--env-size must be >= 2, got {args.env_size}")
    mesh = _ints(args.mesh, "mesh")
    if len(mesh) != 2 or min(mesh) < 3:
        raise ArgumentError("--mesh", f"--mesh must be two integers >= 3 (longitudes,"
                                      f"latitudes), got {args.mesh!r}")
    with _session(args) as glctx:
        scene = envmap.make_scene(glctx, mesh=tuple(mesh), env_size=args.env_size)
        fits = []
        for seed in _seeds(args):
            f = envmap.fit_envmap(glctx, seed, resolution=args.resolution,
                                  iterations=args.iterations, views=args.views, lr=args.lr,
                                  exponent_lr=args.exponent_lr, fit_env=args.fit_env,
                                  env_lr=args.env_lr, scene=scene,
                                  progress=_progress(args, "envmap"))
            fits.append(f)
            print(f"envmap seed {seed}: image RMSE {f.image_rmse[0]:.4g} -> "
                  f"{f.image_rmse[-1]:.3g}, colour error {f.color_error[0]:.3g} -> "
                  f"{f.color_error[-1]:.3g}, exponent error {f.exponent_error[0]:.3g} -> "
                  f"{f.exponent_error[-1]:.3g} (exponent {f.start['exponent']:.1f} -> "
                  f"{f.final['exponent']:.2f}, true {f.true['exponent']:g})"
                  + (f", cube map RMSE {f.env_rmse[0]:.3g} -> {f.env_rmse[-1]:.3g}"
                     if f.fit_env else ""), flush=True)
        paths = figures.envmap_figures(fits, glctx, args.out)
    if args.fit_env:
        met = all(f.env_rmse[-1] < f.env_rmse[0] / 2 for f in fits)
        goal = "every seed: cube map RMSE under half its start"
    else:
        met = all(f.color_error[-1] < ENVMAP_COLOR_GOAL
                  and f.exponent_error[-1] < ENVMAP_EXPONENT_GOAL for f in fits)
        goal = (f"every seed: colour error under {ENVMAP_COLOR_GOAL}, exponent error under "
                f"{ENVMAP_EXPONENT_GOAL}")
    print(_timing_line(f"envmap {args.resolution}x{args.resolution}",
                       [f.timing for f in fits]))
    print(f"goal ({goal}): {'met' if met else 'MISSED'}")
    _finish(args, {"problem": "envmap", "framework": args.framework, "goal_met": bool(met),
                   "runs": [f.summary() for f in fits]}, paths)
    return exit_codes.OK if met else exit_codes.FAIL
