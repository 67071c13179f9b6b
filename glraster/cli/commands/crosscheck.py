"""`glraster crosscheck`: compare glraster with another renderer.

Compare glraster's output with another renderer's.
"""

from __future__ import annotations

import json

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command, non_negative_float
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "crosscheck", __doc__)
    sub = p.add_subparsers(dest="crosscheck_target", metavar="TARGET", required=True)
    q = sub.add_parser(
        "pyrender", help="depth against pyrender (run in a subprocess)",
        description="Render a mesh's linear depth with pyrender (24-bit, 4x MSAA) and with "
                    "glraster (perspective-correct view depth), and report their relative "
                    "difference away from silhouettes.  Exit status 1 if the median exceeds "
                    "--max-median.")
    q.add_argument("--mesh", help="mesh file (OBJ/PLY/GLB/STL); default: a built-in tilted torus")
    q.add_argument("--width", type=int, default=320, help="image width in pixels (320)")
    q.add_argument("--height", type=int, default=240, help="image height in pixels (240)")
    q.add_argument("--platform", choices=("egl", "osmesa"), default="egl",
                   help="PYOPENGL_PLATFORM for pyrender (egl)")
    q.add_argument("--sample", default="auto",
                   help="where glraster samples: auto, center or sampleN (pyrender's MSAA "
                        "sample N); default auto = best median")
    q.add_argument("--margin", type=int, default=1,
                   help="pixels excluded around silhouettes and depth jumps (1)")
    q.add_argument("--max-median", type=non_negative_float, default=1e-4,
                   help="fail if the median relative difference exceeds this (1e-4)")
    q.add_argument("--json", action=OutputFile,
                   metavar="PATH", help="also write the report as JSON")
    add_backend_argument(q)
    q.set_defaults(func=_pyrender)


def _pyrender(args) -> int:
    from glraster.gpu.context import Context
    from glraster.studies.crosscheck import crosscheck_pyrender

    for name, least in (("width", 1), ("height", 1), ("margin", 0)):
        if getattr(args, name) < least:
            raise ArgumentError(f"--{name}", f"--{name} must be >= {least}, "
                                             f"got {getattr(args, name)}")
    rep = crosscheck_pyrender(args.mesh, resolution=(args.height, args.width),
                              ctx=Context(backend=args.backend), platform=args.platform,
                              sample=args.sample, margin=args.margin)
    print(rep.summary())
    if args.json:
        from glraster.io.atomic import write_text

        write_text(args.json, json.dumps(rep.to_dict(), indent=2))
    ok = rep.median_rel <= args.max_median
    print(f"  median {'<=' if ok else '>'} {args.max_median:g}: {'PASS' if ok else 'FAIL'}")
    return exit_codes.OK if ok else exit_codes.FAIL
