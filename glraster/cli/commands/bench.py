"""`glraster bench`: time every method against the fill limit, the reference and pyrender.

For each method x scene x resolution x triangle count: first-run and warm median time,
error against the float64 reference, ratio to the fill limit (a bare moderngl draw of the
same targets), peak host memory, and pyrender (depth only) as the peer; then the README
headline figures and each skip switch on/off. The quick preset takes ~1-2 minutes, the
full one ~50 minutes on 2 cores (docs/performance.md).
"""

from __future__ import annotations

import json
import sys

from glraster.cli import exit_codes
from glraster.cli.errors import describe
from glraster.cli.commands import add_command, comma_list
from glraster.io.atomic import write_text
from glraster.io.destinations import OutputFile


def _add_presets(parser) -> None:
    """``--preset quick|full`` and its two shorthands ``--quick`` / ``--full``."""
    parser.add_argument("--preset", choices=("quick", "full"), default="quick",
                        help="case grid (default: quick)")
    for name in ("quick", "full"):
        parser.add_argument(f"--{name}", dest="preset", action="store_const", const=name,
                            help=f"same as --preset {name}")


def register(subparsers) -> None:
    p = add_command(subparsers, "bench", __doc__)
    _add_presets(p)
    p.add_argument("--methods", default=None, type=comma_list, metavar="LIST",
                   help="comma-separated methods (default: all)")
    p.add_argument("--backend", default="egl", choices=("egl", "osmesa"),
                   help="OpenGL backend (default: egl, the driver pyrender uses too)")
    p.add_argument("--json", action=OutputFile,
                   default=None, metavar="FILE", help="write all results as JSON")
    p.add_argument("--plot", action=OutputFile, default=None, metavar="FILE",
                   help="write the log-log time/error Pareto plot (PNG)")
    p.add_argument("--no-pyrender", action="store_true", help="skip the pyrender peer")
    p.add_argument("--max-reference-pixels", type=int, default=1 << 24, metavar="N",
                   help="compute errors only for images of at most N pixels (default 2^24: "
                        "every size up to 4096x4096)")
    p.set_defaults(func=run)

    d = subparsers.add_parser(
        "bench-diff", help="time the differentiable ops (derivatives, backward passes, "
                           "determinism, interpolate against plain PyTorch)",
        description="For each resolution x triangle count on the benchmark terrain: "
                    "rasterize with and without rast_db, its backward (atomic and "
                    "deterministic) against the forward, and interpolate forward+backward "
                    "through glraster.torch against the same math in plain PyTorch "
                    "(glraster.studies.torch_interpolate_baseline), as medians of "
                    "interleaved rounds, with the goals met or missed. Needs the [torch] "
                    "extra. The quick preset (256/1024 px, 1k/20k triangles) takes about a "
                    "minute, the full one (256/512/1024 px, 1k/20k/100k triangles, plus a cProfile breakdown of "
                    "two cells) about 4 minutes on 2 cores (docs/differentiable.md, Speed).")
    _add_presets(d)
    d.add_argument("--repeats", type=int, default=None, metavar="N",
                   help="interleaved rounds per cell (default: the preset's)")
    d.add_argument("--backend", default="egl", choices=("egl", "osmesa"),
                   help="OpenGL backend (default: egl)")
    d.add_argument("--json", action=OutputFile,
                   default=None, metavar="FILE", help="write all results as JSON")
    d.set_defaults(func=run_diff)


def run_diff(args) -> int:
    from glraster.cli.commands.check import Progress

    try:
        from glraster.studies import diff_bench
    except ImportError as exc:  # torch is the optional [torch] extra
        print(f"glraster bench-diff: needs the [torch] extra ({exc})", file=sys.stderr)
        return exit_codes.USAGE
    overrides = {}
    if args.repeats is not None:
        if args.repeats < 1:
            print("glraster bench-diff: --repeats must be >= 1", file=sys.stderr)
            return exit_codes.USAGE
        overrides["repeats"] = args.repeats
    result = diff_bench.run(args.preset, backend=args.backend, progress=Progress(),
                            **overrides)
    m = result["machine"]
    print(f"{m['renderer']}, {m['cpus']} CPUs, torch {m['torch']} ({m['torch_threads']} "
          f"threads), accumulation {m['accumulation']}; medians of per-round ratios "
          f"(wall), {result['settings']['repeats']} rounds\n")
    print(diff_bench.table(result))
    print("\ngoals:")
    for name, (goal, op, sizes) in diff_bench.GOALS.items():
        g = result["goals"].get(name)
        if g:
            where = f" at {', '.join(f'{s}²' for s in sizes)}" if sizes else ""
            print(f"  {name} {op} {goal}{where}: met in {g['met']} of {g['cells']} cells")
    same = [c["same_math"] for c in result["cells"]]
    print(f"  baseline out / out_da bit-identical to glraster's: "
          f"{sum(s['out_equal'] and s['out_da_equal'] for s in same)} of {len(same)} cells")
    for p in result["profile"]:
        print(f"\nwhere the time goes, {p['resolution'][0]}², {p['triangles']} triangles "
              "(ms per call, cProfile):")
        for call, phases in p["ms_per_call"].items():
            parts = ", ".join(f"{k} {v:.1f}" for k, v in phases.items() if k != "total")
            print(f"  {call} {phases['total']:.1f}: {parts}")
    print(f"\n{result['seconds']:.0f} s")
    if args.json:
        write_text(args.json, json.dumps(result, indent=1, default=float))
        print(f"wrote {args.json}")
    return exit_codes.OK


def _print_cases(cases) -> None:
    print(f"{'method':<14}{'scene':<9}{'res':>6}{'tris':>9}{'first ms':>10}{'warm ms':>10}"
          f"{'x fill':>8}{'persp max':>11}{'screen max':>11}{'err/tol':>9}{'host MiB':>9}")
    for c in cases:
        err = c["error"]
        pm = err.get("persp", {}).get("max")
        sm = err.get("screen", {}).get("max")
        ratio = max((v.get("worst_ratio", 0) for v in err.values() if isinstance(v, dict)),
                    default=None)
        fmt = lambda v: f"{v:11.2e}" if v is not None else f"{'-':>11}"  # noqa: E731
        print(f"{c['method']:<14}{c['scene']:<9}{c['resolution'][0]:>6}{c['triangles']:>9}"
              f"{c['first_ms']:>10.2f}{c['warm_ms']:>10.2f}{c['fill_ratio']:>8.2f}"
              f"{fmt(pm)}{fmt(sm)}{(f'{ratio:9.3f}' if ratio is not None else f'{chr(45):>9}')}"
              f"{c['peak_host_mib']:>9.1f}")
        if c.get("pyrender"):
            p = c["pyrender"]
            print(f"{'':<14}pyrender depth-only {p['warm_ms']:.2f} ms vs glraster depth-only "
                  f"{p['glraster_depth_ms']:.2f} ms: glraster {p['ratio']:.2f}x faster")


def run(args) -> int:
    from glraster.cli.commands.check import Progress
    from glraster.studies import bench

    if not args.no_pyrender and not bench.pyrender_installed():
        print(f"glraster bench: {bench.PYRENDER_MISSING}", file=sys.stderr)
        return exit_codes.USAGE
    overrides = {}
    if args.methods:
        overrides["methods"] = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    try:
        result = bench.run(args.preset, backend=args.backend, progress=Progress(),
                           with_pyrender=not args.no_pyrender,
                           max_reference_pixels=args.max_reference_pixels, **overrides)
    except ValueError as exc:
        print(f"glraster bench: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.USAGE
    _print_cases(result["cases"])
    head = result["headline"]
    print(f"\nheadline ({head['scene']}):")
    hf = head["hw_over_fill"]
    print(f"  hw {head['hw_ms']:.1f} ms vs fill limit {head['fill_ms']:.1f} ms: "
          f"{hf['median']:.3f}x (pairs {hf['pairs']}, min {hf['min']:.3f}, max {hf['max']:.3f})")
    oh = head["overhead_64x64_ms"]
    print(f"  64x64 one triangle warm: {oh['median']:.3f} ms median, {oh['p90']:.3f} ms p90; "
          + ", ".join(f"{m} {v:.3f}" for m, v in oh["per_method"].items()))
    ref = head["reference_mpix_per_s"]
    print(f"  reference: {ref['median']:.2f} Mpixel/s (best {ref['best']:.2f})")
    pr = head["pyrender"]
    if pr is None:
        print("  pyrender: skipped (--no-pyrender)")
    else:
        print(f"  pyrender depth-only {pr['pyrender_depth_ms']:.1f} ms vs glraster depth-only "
              f"{pr['glraster_depth_ms']:.1f} ms ({pr['speedup_depth_only']:.2f}x), glraster "
              f"all outputs {pr['glraster_all_outputs_ms']:.1f} ms")
    print("\nskip switches (on / off, median ms):")
    width = max(map(len, result["skips"]), default=0) + 2
    for label, v in result["skips"].items():
        print(f"  {label:<{width}}{v['on_ms']:>9.2f}{v['off_ms']:>9.2f}")
    if args.json:
        write_text(args.json, json.dumps(result, indent=1, default=float))
        print(f"wrote {args.json}")
    if args.plot:
        bench.pareto_plot(result, args.plot)
        print(f"wrote {args.plot}")
    return exit_codes.OK
