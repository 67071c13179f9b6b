"""`glraster render`: render a catalog scene or a scene file (.npz/.json) to an EXR.

Rasterize a scene on the GPU (or with the float64 reference) and write a multi-channel
EXR: persp.b0..b2, screen.b0..b2, depth.Z and the exact triangle id, upright. Scene files:
.npz with pos (V,4), tri (T,3), resolution (2,) = (H, W); or .json with the same keys, or
a recipe {name, resolution, builder, params} as in the catalog.
"""

from __future__ import annotations

import sys
import time

from glraster.cli import exit_codes
from glraster.cli.errors import describe
from glraster.cli.commands import add_backend_argument, add_command
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "render", __doc__)
    p.add_argument("scene", metavar="SCENE_OR_FILE",
                   help="catalog scene name (see 'glraster check --list') or scene file")
    p.add_argument("-o", "--output", action=OutputFile,
                   required=True, metavar="OUT.exr", help="EXR to write")
    add_backend_argument(p)
    p.add_argument("--outputs", default=None, metavar="LIST",
                   help="comma-separated subset of persp,screen,depth,tri_id "
                        "(default: the scene's outputs)")
    p.add_argument("--reference", action="store_true",
                   help="write the float64 reference (rounded to float32) instead of the GPU")
    p.add_argument("--crop", action="store_true",
                   help="store only the bounding box of covered pixels (lossless)")
    p.add_argument("--png", action=OutputFile, default=None, metavar="OUT.png",
                   help="also write a preview PNG of the perspective barycentrics")
    p.add_argument("--server", default=None, metavar="URL",
                   help="render on a glraster service (glraster serve) instead of a local "
                        "context; the arrays come back bit for bit. Token: --token-file or "
                        "$GLRASTER_TOKEN")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help="bearer token for --server (the first token line of FILE)")
    p.set_defaults(func=run)


def run(args) -> int:
    from glraster.conformance.scenes import resolve

    try:
        scene = resolve(args.scene)
        outputs = scene.outputs
        if args.outputs:
            from glraster.validate import outputs as check_outputs

            outputs = check_outputs([o.strip() for o in args.outputs.split(",") if o.strip()])
        if not str(args.output).lower().endswith(".exr"):
            raise ArgumentError("output", f"output must end in .exr, got {args.output!r}")
        if args.png is not None and not str(args.png).lower().endswith(".png"):
            raise ArgumentError("png", f"png must end in .png, got {args.png!r}")
        if args.server is not None and not args.server.strip():
            raise ArgumentError(
                "--server", "--server needs the service's URL (http://HOST:PORT), got an "
                            "empty string")
    except ValueError as exc:
        print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.USAGE
    t = time.perf_counter()
    if args.server is not None:
        try:
            raster, producer = _remote(args, scene, outputs)
        except ValueError as exc:
            print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
            return exit_codes.USAGE
        except ConnectionError as exc:
            print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
            return exit_codes.NO_BACKEND
    elif args.reference:
        from glraster.reference import rasterize as ref_rasterize

        raster = ref_rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs)
        producer = "glraster.reference.rasterize (float64, fill rule llvmpipe), rounded to float32"
    else:
        from glraster.errors import BackendUnavailable
        from glraster.gpu.context import Context
        from glraster.gpu.rasterize import rasterize

        try:
            ctx = Context(backend=args.backend)
        except (BackendUnavailable, ValueError) as exc:
            print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
            return exit_codes.NO_BACKEND
        try:
            raster = rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=outputs)
        except ValueError as exc:
            print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
            return exit_codes.USAGE
        producer = f"glraster.rasterize on {ctx.renderer} via {ctx.backend}, {ctx.gl_version}"
    seconds = time.perf_counter() - t
    _write(args, raster, outputs, metadata={"scene": scene.name, "scene_hash": scene.hash,
                                            "producer": producer})
    h, w = scene.resolution
    tris = f"{len(scene.tri)} triangle" + ("" if len(scene.tri) == 1 else "s")
    print(f"{scene.name}: {h}x{w} (HxW), {tris}, {int(raster.mask.sum())} "
          f"pixels covered, {seconds:.3f} s -> {args.output} ({', '.join(outputs)})")
    if args.png:
        print(f"preview: {args.png}")
    return exit_codes.OK


def _write(args, raster, outputs, metadata) -> None:
    """Write the EXR (and the --png preview): both or neither. Each goes to a temporary
    file beside its target, and the targets are replaced only once both are complete."""
    from contextlib import ExitStack

    from glraster.io import exr
    from glraster.io.atomic import atomic_write

    with ExitStack() as stack:
        exr_tmp = stack.enter_context(atomic_write(args.output))
        png_tmp = stack.enter_context(atomic_write(args.png)) if args.png else None
        exr.write_raster(exr_tmp, **{n: getattr(raster, n) for n in outputs},
                         window="covered" if args.crop else "full", metadata=metadata)
        if png_tmp is not None:
            from glraster.io.png import bary_rgb, write_png

            bary = raster.persp if raster.persp is not None else raster.screen
            write_png(png_tmp, bary_rgb(bary, raster.mask))


def _token(args):
    import os

    if args.token_file:
        from pathlib import Path

        try:
            lines = [ln.strip() for ln in Path(args.token_file).read_text().splitlines()]
        except OSError as exc:
            raise ArgumentError(
                "token_file", f"token file {args.token_file!r}: {exc.strerror or exc}") from None
        tokens = [ln for ln in lines if ln and not ln.startswith("#")]
        if not tokens:
            raise ArgumentError("token_file", f"token file {args.token_file!r} holds no token")
        return tokens[0]
    return os.environ.get("GLRASTER_TOKEN") or None


def _remote(args, scene, outputs):
    """Render ``scene`` on the service at ``args.server``: (raster, producer). A request the
    service refuses is a ValueError (exit 2); one it cannot serve a ConnectionError (exit 3)."""
    from glraster.client import Client, ServiceError, ServiceUnavailable

    try:
        with Client(args.server, _token(args)) as client:
            raster = client.rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs,
                                      reference=args.reference)
            renderer = raster.info["headers"].get("x-glraster-source", "gpu")
            info = client.info().get("driver", {}) if not args.reference else {}
    except ServiceUnavailable as exc:
        if not exc.status:   # no answer: the message names the URL and the cause
            raise ConnectionError(str(exc)) from None
        raise ConnectionError(f"the service at {args.server} could not render: {exc}") from None
    except ServiceError as exc:
        raise ArgumentError(   # the request field the service names (pos, tri, resolution)
            exc.field or "scene",
            f"the service at {args.server} refused the request: {exc}") from None
    if renderer == "reference":
        producer = (f"glraster.reference.rasterize (float64, fill rule llvmpipe) at "
                    f"{args.server}, rounded to float32")
    else:
        producer = (f"glraster.rasterize on {info.get('renderer', '?')} via "
                    f"{info.get('backend', '?')}, {info.get('gl_version', '?')} at {args.server}")
    return raster, producer
