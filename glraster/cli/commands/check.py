"""`glraster check`: render the scene catalog and compare with the reference and goldens.

Render every catalog scene on the current OpenGL driver, compare it pixel by pixel with
the float64 reference (per-pixel tolerances from the error model, exact coverage where the
fill rule is modeled) and check the golden EXRs bit for bit. Exits 1 on any failure.
"""

from __future__ import annotations

import contextlib
import sys
import time

from glraster.cli import exit_codes
from glraster.cli.errors import describe as describe_error
from glraster.cli.commands import add_backend_argument, add_command, comma_list
from glraster.io.destinations import OutputFile, OutputFolder


def register(subparsers) -> None:
    p = add_command(subparsers, "check", __doc__)
    add_backend_argument(p)
    p.add_argument("--scenes", default=None, type=comma_list, metavar="PATTERN",
                   help="comma-separated fnmatch patterns of scene names (default: all)")
    p.add_argument("--method", default="hw", metavar="NAME",
                   help="barycentric method to check: hw (default), divw, homogeneous, "
                        "homogeneous64 or solve4; each is judged by its own error model")
    p.add_argument("--junit", action=OutputFile,
                   default=None, metavar="FILE", help="write JUnit XML here")
    p.add_argument("--html", action=OutputFolder, default=None, metavar="DIR",
                   help="write an HTML report (DIR/index.html)")
    p.add_argument("--mutants", nargs="?", const="all", default=None, type=comma_list,
                   metavar="PATTERN",
                   help="also run the fault-injection mutants (all, or those matching "
                        "PATTERN, comma-separated fnmatch patterns); each must be caught by "
                        "some scene")
    p.add_argument("--golden-dir", default=None, metavar="DIR",
                   help="golden folder (default: $GLRASTER_GOLDEN_DIR or golden/)")
    p.add_argument("--no-golden", action="store_true", help="skip the golden comparison")
    p.add_argument("--list", action="store_true", help="list the matching scenes and exit")
    p.add_argument("--shard", default=None, metavar="I/N",
                   help="check only shard I of N of the matching scenes (balanced by cost, the "
                        "same split on every runner); with --mutants, shard 1 runs the mutant "
                        "pass. Join the shards' --junit files with 'glraster junit-merge'")
    p.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help="run on Ray (glraster.cluster; pip install 'glraster[ray]'): every "
                        "scene x method x driver as a task on the actors of its driver, one "
                        "merged JUnit and HTML report with a driver matrix. ADDRESS: a "
                        "cluster's; without it $RAY_ADDRESS, else a local cluster on this "
                        "machine (docs/cluster.md)")
    p.add_argument("--drivers", default=None, type=comma_list, metavar="A,B",
                   help="with --ray: the drivers to check, comma-separated (default: every "
                        "driver the cluster advertises); on one machine llvmpipe, softpipe, "
                        "zink are selected by GALLIUM_DRIVER")
    p.add_argument("--methods", default=None, type=comma_list, metavar="M1,M2",
                   help="with --ray: comma-separated methods (default: --method)")
    p.set_defaults(func=run)


class Progress:
    """A one-line progress bar on stderr (a line per step when stderr is not a terminal)."""

    def __init__(self, stream=None, width=30):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.width = width
        self.t0 = time.perf_counter()

    def __call__(self, i, total, label):
        done = int(self.width * i / max(total, 1))
        bar = "#" * done + "." * (self.width - done)
        text = f"[{bar}] {i:>3}/{total} {time.perf_counter() - self.t0:6.1f}s {label}"
        if self.tty:
            self.stream.write("\r" + text[:110].ljust(110))
            if i >= total:
                self.stream.write("\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


def run(args) -> int:
    from glraster.conformance.scenes import describe, list_scenes

    names = list_scenes(args.scenes)
    if not names:
        print(f"glraster check: no scene matches {args.scenes!r}; known: "
              f"{', '.join(list_scenes())}", file=sys.stderr)
        return exit_codes.USAGE
    shard = mutant_scenes = None
    if args.shard:
        from glraster.conformance.check import shard_scenes

        try:
            shard = tuple(int(v) for v in args.shard.split("/"))
            if len(shard) != 2:
                raise ValueError
            all_names, names = names, shard_scenes(names, *shard)
        except ValueError:
            print(f"glraster check: --shard must be I/N with 1 <= I <= N, got {args.shard!r}",
                  file=sys.stderr)
            return exit_codes.USAGE
        if args.mutants:
            if shard[0] == 1:
                mutant_scenes = all_names
            else:
                print(f"glraster check: shard {args.shard}: the mutant pass runs in shard 1",
                      file=sys.stderr)
                args.mutants = None
    if args.ray is None and (args.drivers or args.methods):
        print("glraster check: --drivers and --methods need --ray", file=sys.stderr)
        return exit_codes.USAGE
    if args.list:
        for n in names:
            print(f"{n:<28} {describe(n)}")
        return exit_codes.OK
    from glraster.conformance import check, mutants
    from glraster.errors import BackendUnavailable
    from glraster.gpu.context import Context
    from glraster.gpu.rasterize import METHODS

    if args.method not in METHODS:
        print(f"glraster check: --method must be one of {', '.join(sorted(METHODS))}, got "
              f"{args.method!r}", file=sys.stderr)
        return exit_codes.USAGE
    if args.mutants:
        if args.method != "hw":
            print("glraster check: --mutants injects faults into the hw shaders; it cannot "
                  f"be combined with --method {args.method}", file=sys.stderr)
            return exit_codes.USAGE
        try:
            mutants.select(args.mutants)
        except ValueError as exc:
            print(f"glraster check: {describe_error(exc, args)}", file=sys.stderr)
            return exit_codes.USAGE
    if args.ray is not None:
        return _run_fleet(args, names)
    try:
        ctx = Context(backend=args.backend)
    except (BackendUnavailable, ValueError) as exc:
        print(f"glraster check: {describe_error(exc, args)}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    with contextlib.ExitStack() as stack:
        report = None
        if args.html:   # (a run that fails leaves the report that was there as it was)
            from glraster.conformance.html_report import HtmlReport

            report = stack.enter_context(HtmlReport(args.html))
        result = check.run(ctx, names, method=args.method, golden_dir=args.golden_dir,
                           check_golden=not args.no_golden,
                           mutants=bool(args.mutants), mutant_pattern=args.mutants,
                           on_scene=report.add_scene if report else None, progress=Progress(),
                           **({"mutant_scenes": mutant_scenes} if mutant_scenes else {}))
        result.shard = shard
        print(check.format_table(result))
        if args.junit:
            from glraster.conformance import junit

            print(f"JUnit XML: {junit.write(result, args.junit)}")
        if report:
            print(f"HTML report: {report.finish(result)}")
    return exit_codes.OK if result.ok else exit_codes.FAIL


def _run_fleet(args, names) -> int:
    """``check --ray``: the catalog x methods x drivers on Ray (glraster.cluster.fleet)."""
    from glraster.gpu.rasterize import METHODS

    methods = [m.strip() for m in (args.methods or args.method).split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if not methods or bad:
        print(f"glraster check: --methods must be a comma-separated list of "
              f"{', '.join(sorted(METHODS))}, got {args.methods!r}", file=sys.stderr)
        return exit_codes.USAGE
    for flag, value in (("--mutants", args.mutants), ("--shard", args.shard)):
        if value:
            print(f"glraster check: {flag} cannot be combined with --ray (the fleet runs the "
                  "whole catalog; mutants run in a sequential check)", file=sys.stderr)
            return exit_codes.USAGE
    from glraster.cluster import fleet, runtime
    drivers = None
    if args.drivers:
        try:
            drivers = runtime.check_driver_names(args.drivers)
        except ValueError as exc:
            print(f"glraster check: {describe_error(exc, args)}", file=sys.stderr)
            return exit_codes.USAGE

    def show_nodes(nodes):
        for n in nodes:
            state = f"GL up: {n.renderer}" if n.ok else f"GL DID NOT COME UP: {n.error}"
            print(f"node {n.node} driver {n.driver}: {state}", file=sys.stderr)

    result = fleet.run_check(names, drivers=drivers, methods=methods, address=args.ray or None,
                             backend=args.backend,
                             golden_dir=args.golden_dir, check_golden=not args.no_golden,
                             images=bool(args.html), progress=Progress(), on_nodes=show_nodes)
    for d, m, r in result.runs:
        print(f"== driver {d}, method {m} ==")
        print(check_format(r))
        print()
    for d, why in result.missing.items():
        print(f"driver {d}: NOT RUN: {why}")
    down = [n for n in result.nodes if not n.ok]
    for n in down:
        print(f"node {n.node} (driver {n.driver}) left out: {n.error}")
    print(f"fleet: {len(result.runs)} driver run(s), {result.tasks} tasks, "
          f"{len(result.nodes) - len(down)}/{len(result.nodes)} workers up, "
          f"{result.seconds:.1f} s: " + ("PASS" if result.ok else "FAIL"))
    if args.junit:
        from glraster.conformance import junit

        print(f"JUnit XML: {junit.write_tree(fleet.to_junit(result), args.junit)}")
    if args.html:
        print(f"HTML report: {fleet.write_html(result, args.html)}")
    if not result.runs:
        return exit_codes.NO_BACKEND
    return exit_codes.OK if result.ok else exit_codes.FAIL


def check_format(result) -> str:
    from glraster.conformance.check import format_table

    return format_table(result)
