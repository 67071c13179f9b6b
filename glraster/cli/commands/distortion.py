"""`glraster distortion`: render the affine vs perspective-correct texture comparison.

Render a tilted checkerboard plane and a checkered cube with affine (noperspective) and
perspective-correct uv, and write PNGs (affine, correct, uv-error heatmap, labeled side-
by-side figure), an EXR and the worked example (affine depth 4.5 against true 4).
"""

from __future__ import annotations

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFolder


def register(subparsers) -> None:
    p = add_command(subparsers, "distortion", __doc__)
    p.add_argument("--out", action=OutputFolder, default="out/distortion", metavar="DIR",
                   help="output directory (out/distortion)")
    p.add_argument("--width", type=int, default=480, help="image width per panel (480)")
    p.add_argument("--height", type=int, default=360, help="image height per panel (360)")
    p.add_argument("--supersample", type=int, default=3,
                   help="samples per pixel along each axis (3)")
    add_backend_argument(p)
    p.set_defaults(func=_run)


def _run(args) -> int:
    from glraster.gpu.context import Context
    from glraster.studies.distortion import write_comparison

    for name in ("width", "height", "supersample"):
        if getattr(args, name) < 1:
            raise ArgumentError(f"--{name}", f"--{name} must be >= 1, got {getattr(args, name)}")
    ctx = Context(backend=args.backend)
    # the panels are rendered at supersample times their size, then box-filtered
    for name in ("width", "height"):
        rendered = getattr(args, name) * args.supersample
        if rendered > ctx.max_texture_size:
            raise ArgumentError(f"--{name}", f"--{name} {getattr(args, name)} x --supersample "
                                             f"{args.supersample} = {rendered} pixels exceeds "
                                             f"the driver's maximum of {ctx.max_texture_size}")
    summary = write_comparison(args.out, (args.height, args.width), args.supersample, ctx=ctx)
    print("\n".join(summary["text"]))
    for name, st in summary["scenes"].items():
        print(f"{name}: affine uv error max {st['max_uv_error']:.3f}, mean "
              f"{st['mean_uv_error']:.3f} checker squares; "
              f"{100 * st['pixels_changed']:.1f}% of covered pixels change color")
    print("wrote " + ", ".join(summary["files"]))
    return exit_codes.OK
