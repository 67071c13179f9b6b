"""`glraster render`: render a catalog scene or a scene file (.npz/.json) to an EXR or .npz.

Rasterize a scene on the GPU (or with the float64 reference) and write a multi-channel
EXR: persp.b0..b2, screen.b0..b2, depth.Z and the exact triangle id, upright; or an .npz
of the arrays as glraster.rasterize returns them (bit for bit; a multisampled scene's
per-sample arrays only fit there). Scene files: .npz with pos (V,4), tri (T,3),
resolution (2,) = (H, W); or .json with the same keys, or a recipe {name, resolution,
builder, params} as in the catalog; samples and interpolation as the scene sets them.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from glraster.cli import exit_codes
from glraster.cli.errors import describe
from glraster.cli.commands import add_backend_argument, add_command, comma_list
from glraster.errors import ArgumentError
from glraster.types import INTERPOLATIONS
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "render", __doc__)
    p.add_argument("scene", metavar="SCENE_OR_FILE",
                   help="catalog scene name (see 'glraster check --list') or scene file")
    p.add_argument("-o", "--output", action=OutputFile, required=True,
                   metavar="OUT.exr|OUT.npz",
                   help="EXR or .npz to write (.npz: the arrays, the mask and the sample "
                        "positions bit for bit, and a JSON metadata string)")
    add_backend_argument(p)
    p.add_argument("--outputs", default=None, type=comma_list, metavar="LIST",
                   help="comma-separated subset of persp,screen,depth,tri_id "
                        "(default: the scene's outputs)")
    p.add_argument("--samples", type=int, default=None, metavar="S",
                   help="samples per pixel (default: the scene's; 1 unless it sets more): "
                        "1 or a count the driver offers ('glraster info'); above 1 the "
                        "output must be an .npz")
    p.add_argument("--interpolation", default=None, choices=INTERPOLATIONS,
                   help="where multisampled barycentrics are evaluated (default: the "
                        "scene's, else center)")
    p.add_argument("--reference", action="store_true",
                   help="write the float64 reference instead of the GPU (rounded to float32 "
                        "in an EXR, float64 in an .npz)")
    p.add_argument("--crop", action="store_true",
                   help="store only the bounding box of covered pixels in the EXR (lossless)")
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
        scene = _with_options(resolve(args.scene), args)
        outputs = scene.outputs
        if args.outputs:
            from glraster.validate import outputs as check_outputs

            outputs = check_outputs([o.strip() for o in args.outputs.split(",") if o.strip()])
        _check_output(args, scene)
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

        raster = ref_rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs,
                               samples=scene.samples, interpolation=scene.interpolation)
        producer = "glraster.reference.rasterize (float64, fill rule llvmpipe)" + \
            (", rounded to float32" if _is_exr(args.output) else "")
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
            raster = rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=outputs,
                               samples=scene.samples, interpolation=scene.interpolation)
        except ValueError as exc:
            print(f"glraster render: {describe(exc, args)}", file=sys.stderr)
            return exit_codes.USAGE
        producer = f"glraster.rasterize on {ctx.renderer} via {ctx.backend}, {ctx.gl_version}"
    seconds = time.perf_counter() - t
    metadata = {"scene": scene.name, "scene_hash": scene.hash, "producer": producer}
    if scene.samples > 1:
        metadata.update(samples=scene.samples, interpolation=scene.interpolation)
    _write(args, raster, outputs, metadata)
    h, w = scene.resolution
    tris = f"{len(scene.tri)} triangle" + ("" if len(scene.tri) == 1 else "s")
    covered = _pixel_mask(raster.mask)
    per_sample = f", {scene.samples} samples ({scene.interpolation})" if scene.samples > 1 else ""
    print(f"{scene.name}: {h}x{w} (HxW){per_sample}, {tris}, {int(covered.sum())} "
          f"pixels covered, {seconds:.3f} s -> {args.output} ({', '.join(outputs)})")
    if args.png:
        print(f"preview: {args.png}")
    return exit_codes.OK


def _with_options(scene, args):
    """``scene`` at the --samples / --interpolation given (validated, named by option)."""
    from dataclasses import replace

    from glraster import validate

    changes = {}
    if args.samples is not None:
        changes["samples"] = validate.samples(args.samples)
    if args.interpolation is not None:
        changes["interpolation"] = args.interpolation
    return replace(scene, **changes) if changes else scene


def _is_exr(path) -> bool:
    return str(path).lower().endswith(".exr")


def _check_output(args, scene) -> None:
    """ArgumentError naming the option when OUT's type cannot hold what is asked for."""
    out = str(args.output)
    if not (_is_exr(out) or out.lower().endswith(".npz")):
        raise ArgumentError("output", f"output must end in .exr or .npz, got {out!r}")
    if _is_exr(out) and scene.samples > 1:
        raise ArgumentError(
            "output", f"{scene.name} has {scene.samples} samples a pixel and an EXR holds one "
                      f"value a pixel: write an .npz (-o {Path(out).with_suffix('.npz')})")
    if args.crop and not _is_exr(out):
        raise ArgumentError("crop", "--crop crops an EXR's data window; an .npz holds the "
                                    "whole arrays")


def _write(args, raster, outputs, metadata) -> None:
    """Write the EXR or .npz (and the --png preview): both or neither. Each goes to a
    temporary file beside its target, and the targets are replaced only once both are
    complete."""
    from contextlib import ExitStack

    from glraster.io.atomic import atomic_write

    with ExitStack() as stack:
        out_tmp = stack.enter_context(atomic_write(args.output))
        png_tmp = stack.enter_context(atomic_write(args.png)) if args.png else None
        arrays = {n: getattr(raster, n) for n in outputs}
        if _is_exr(args.output):
            from glraster.io import exr

            exr.write_raster(out_tmp, **arrays, window="covered" if args.crop else "full",
                             metadata=metadata)
        else:
            from glraster.io.npz import write_npz

            arrays.update(mask=raster.mask, sample_positions=raster.sample_positions,
                          metadata=np.array(json.dumps(metadata)))
            Path(out_tmp).write_bytes(write_npz(arrays))
        if png_tmp is not None:
            from glraster.io.png import bary_rgb, write_png

            write_png(png_tmp, bary_rgb(*_preview(raster)))


def _pixel_mask(mask):
    """(H, W) bool: pixels with a covered sample, from a (H, W) or (H, W, S) mask."""
    return mask.any(axis=2) if mask.ndim == 3 else mask


def _preview(raster):
    """(bary (H, W, 3) or None, mask (H, W)) for the preview picture: the perspective
    barycentrics (else window-space), of the pixel's lowest-numbered covered sample when
    they are per sample (the value a "center" raster keeps, glraster.types.Raster)."""
    from glraster.types import first_covered_sample, per_pixel

    bary = raster.persp if raster.persp is not None else raster.screen
    if bary is not None and bary.ndim == 4:
        bary = per_pixel(bary, first_covered_sample(raster.mask))
    return bary, _pixel_mask(raster.mask)


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
                                      reference=args.reference, samples=scene.samples,
                                      interpolation=scene.interpolation)
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
                    f"{args.server}" + (", rounded to float32" if _is_exr(args.output) else ""))
    else:
        producer = (f"glraster.rasterize on {info.get('renderer', '?')} via "
                    f"{info.get('backend', '?')}, {info.get('gl_version', '?')} at {args.server}")
    return raster, producer
