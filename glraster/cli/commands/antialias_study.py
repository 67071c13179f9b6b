"""`glraster antialias-study`: 1 sample, SSAA, MSAA and analytic AA against the exact image.

Render four scenes (a fan of wedges with edges at 36 angles, thin slivers, a receding
near-clipped floor of dark squares, the same floor as a two-colour checkerboard mesh) with
one sample per pixel, supersampling 2x2, 4x4 and 8x8, multisampling at every sample count
the driver offers and glraster.diff's analytic antialias op, and measure each image
against the exact box-filtered one (glraster.reference.visible_area: exact visible areas
times flat values): RMSE and max over edge pixels, and the median time.
Prints the table; writes antialias.json, antialias_error_time.png and antialias_zoom.png.
"""

from __future__ import annotations

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFolder


def register(subparsers) -> None:
    p = add_command(subparsers, "antialias-study", __doc__)
    p.add_argument("--out", action=OutputFolder, default="out/antialias", metavar="DIR",
                   help="output directory (out/antialias)")
    p.add_argument("--size", type=int, default=128, metavar="N",
                   help="image width and height in pixels (128)")
    p.add_argument("--repeats", type=int, default=5,
                   help="timed runs per method and scene; the median is reported (5)")
    add_backend_argument(p)
    p.set_defaults(func=_run)


def _run(args) -> int:
    from glraster.gpu.context import Context
    from glraster.studies.antialias import write_study

    if args.size < 16:
        raise ArgumentError("--size", f"--size must be at least 16 pixels, got {args.size}")
    ctx = Context(backend=args.backend)
    result = write_study(args.out, (args.size, args.size), args.repeats, ctx=ctx)
    print(f"{result['renderer']} ({result['backend']}), {args.size}x{args.size}, median of "
          f"{result['repeats']} runs")
    print("\n".join(result["text"]))
    print("wrote " + ", ".join(result["files"]))
    return exit_codes.OK
