"""`glraster golden`: regenerate or verify the golden EXRs (reference output).

Golden EXRs hold the float64 reference rounded to float32, one per catalog scene. 'update'
rewrites them; 'check' recomputes the reference and requires every stored bit back.
"""

from __future__ import annotations

import os
import sys
import time

from glraster.cli import exit_codes
from glraster.cli.commands import add_command
from glraster.errors import ArgumentError

GOLDEN_BUDGET_BYTES = 20 * 1024 * 1024


def register(subparsers) -> None:
    p = add_command(subparsers, "golden", __doc__)
    sub = p.add_subparsers(dest="golden_command", metavar="{update,check}")
    sub.required = True
    from glraster.conformance.golden_folder import golden_dir

    default = golden_dir()
    where = (f"golden folder (default: $GLRASTER_GOLDEN_DIR, else the golden/ beside the "
             f"glraster package Python imports, else the copy inside that package; here: "
             f"{default})")
    for name, helptext in (("update", "regenerate golden EXRs from the reference"),
                           ("check", "verify that the reference reproduces every golden bit")):
        q = sub.add_parser(name, help=helptext, description=helptext)
        q.add_argument("names", nargs="*", metavar="NAME",
                       help="scene names or fnmatch patterns (default: all scenes)")
        q.add_argument("--dir", default=None, metavar="DIR", help=where + (
            ". Without --dir or $GLRASTER_GOLDEN_DIR, update writes only to the golden/ of "
            "the source tree the current directory is in: never into an installed package, "
            "nor another checkout" if name == "update" else ""))
        if name == "update":
            q.add_argument("--force", action="store_true",
                           help="rewrite even goldens the reference still reproduces")
        q.set_defaults(func=_update if name == "update" else _check)


def _names(patterns):
    from glraster.conformance.scenes import list_scenes

    if not patterns:
        return list_scenes()
    names = list_scenes(",".join(patterns))
    unmatched = [p for p in patterns if not list_scenes(p)]
    if unmatched:
        raise ArgumentError("names", f"no scene matches {', '.join(unmatched)}; known: "
                                     f"{', '.join(list_scenes())}")
    return names


def _update(args) -> int:
    from glraster.conformance import golden

    from glraster.conformance.golden_folder import unsafe_default

    names = _names(args.names)          # a ValueError is a usage error (exit 2) in main
    unsafe = unsafe_default(args.dir)
    if unsafe:
        target = golden.golden_dir(args.dir)
        raise ArgumentError(
            "--dir", f"not writing goldens to {target}: it is {unsafe}; pass --dir "
                   f"{target} to write there anyway, or --dir DIR for another folder")
    t0 = time.perf_counter()
    written = 0
    for name in names:
        t = time.perf_counter()
        paths = golden.update([name], directory=args.dir, force=args.force)
        state = "written" if paths else "unchanged (reproduced bit for bit)"
        written += len(paths)
        size = golden.golden_path(name, args.dir).stat().st_size / 1024
        print(f"{name:<28} {size:9.1f} KiB  {time.perf_counter() - t:6.2f} s  {state}")
    total = golden.folder_size(args.dir)
    print(f"wrote {written} of {len(names)} golden file(s) to {golden.golden_dir(args.dir)} in "
          f"{time.perf_counter() - t0:.1f} s; folder total {total / 1024 / 1024:.2f} MiB")
    if total > GOLDEN_BUDGET_BYTES:
        print(f"warning: golden folder exceeds the {GOLDEN_BUDGET_BYTES // 1024 // 1024} MiB "
              "budget", file=sys.stderr)
        return exit_codes.FAIL
    return exit_codes.OK


def _check(args) -> int:
    from glraster.conformance import golden

    names = _names(args.names)          # a ValueError is a usage error (exit 2) in main
    folder = golden.golden_dir(args.dir)
    # a folder without one of the goldens asked for is the wrong folder, not N failures
    if not any(golden.golden_path(name, args.dir).is_file() for name in names):
        from_env = args.dir is None and bool(os.environ.get("GLRASTER_GOLDEN_DIR"))
        what = (f"{folder} holds none of the {len(names)} golden EXR(s) asked for"
                if folder.is_dir() else f"no golden folder at {folder}")
        raise ArgumentError("GLRASTER_GOLDEN_DIR" if from_env else "--dir",
                            f"{what}{' (from $GLRASTER_GOLDEN_DIR)' if from_env else ''}: "
                            "name the folder of the golden EXRs, or make them with 'glraster "
                            "golden update'")
    t0 = time.perf_counter()
    bad = 0
    for name in names:
        res = golden.check_scene(golden.load_scene(name), directory=args.dir)
        bad += not res.ok
        print(f"{name:<28} {'ok  ' if res.ok else 'FAIL'} {res.message}")
    total = golden.folder_size(args.dir)
    print(f"{len(names) - bad}/{len(names)} goldens reproduced bit for bit in "
          f"{time.perf_counter() - t0:.1f} s; folder total {total / 1024 / 1024:.2f} MiB")
    return exit_codes.FAIL if bad else exit_codes.OK
