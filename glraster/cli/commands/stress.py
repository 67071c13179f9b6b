"""`glraster stress`: error-vs-parameter sweeps (distance from origin, w ratio, aspect, ...).

Render small stress scenes with every method and compare with an extended-precision truth:
distance from the origin (0..16k px), w ratio (1..1e6), sliver aspect (1..1e6), triangle
size (1e-3..1e3 px), distance to the near plane, huge coordinates. Prints max errors, the
normalized error err / (eps32 (1 + |grad b| d)) and NaN/Inf counts; writes curves as JSON
and PNG. About 3 minutes (the diagonal sweep renders 10000 x 10000 frames; up to 10 GiB of
memory).
"""

from __future__ import annotations

import sys

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command, comma_list
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "stress", __doc__)
    add_backend_argument(p)
    p.add_argument("--sweeps", default=None, type=comma_list, metavar="LIST",
                   help="comma-separated sweeps (default: all of origin, origin_y, origin_xy, origin_w1, "
                        "w_ratio, aspect, size, near, extent, scale)")
    p.add_argument("--methods", default=None, type=comma_list, metavar="LIST",
                   help="comma-separated methods")
    p.add_argument("--json", action=OutputFile,
                   default=None, metavar="FILE", help="write the curves as JSON")
    p.add_argument("--plot", action=OutputFile,
                   default=None, metavar="FILE", help="write the curves as PNG")
    p.set_defaults(func=run)


def run(args) -> int:
    from glraster.cli.commands.check import Progress
    from glraster.gpu.context import Context
    from glraster.gpu.rasterize import METHODS
    from glraster.studies import stress

    sweeps = _names(args.sweeps) if args.sweeps else stress.SWEEPS
    methods = _names(args.methods) if args.methods else tuple(METHODS)
    bad = [s for s in sweeps if s not in stress.SWEEPS] + [m for m in methods if m not in METHODS]
    if bad:
        print(f"glraster stress: unknown sweep or method {bad}; sweeps {stress.SWEEPS}, "
              f"methods {tuple(METHODS)}", file=sys.stderr)
        return exit_codes.USAGE
    ctx = Context(args.backend)
    try:
        result = stress.run(sweeps, methods, ctx=ctx, progress=Progress())
    finally:
        ctx.release()
    nonfinite = 0
    for sweep, data in result.items():
        print(f"\n{sweep}: " + " ".join(f"{v:g}" for v in data["values"]))
        print("  method         max |persp err| / normalized error per point")
        for method, stats in data["methods"].items():
            cells = []
            for s in stats:
                p = s.get("persp")
                nonfinite += s["nonfinite"]
                flag = "!" if s["nonfinite"] else ""
                cells.append(f"{p['max']:.1e}/{p['ratio_max']:.3g}{flag}" if p else "-")
            print(f"  {method:<14}" + " ".join(f"{c:>15}" for c in cells))
    print(f"\n'!' marks points with NaN/Inf in some output ({nonfinite} values in total)")
    if args.json:
        stress.write_json(result, args.json)
        print(f"wrote {args.json}")
    if args.plot:
        stress.plot(result, args.plot)
        print(f"wrote {args.plot}")
    return exit_codes.OK


def _names(text: str) -> tuple:
    """The names of a comma-separated list, blanks dropped ("size," is "size")."""
    return tuple(name.strip() for name in text.split(",") if name.strip())
