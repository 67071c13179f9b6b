"""`glraster batch`: render a dataset of scenes on Ray into .npz shards and a manifest.

Render every scene of IN (a folder of .npz/.json scene files as 'glraster render' reads
them, a .txt list of such files, or a .json views file: a mesh and a camera list) with Ray
Data on a pool of GL workers, into OUT/shard-NNNNN.npz (the arrays of rasterize, row 0 at
the bottom) and OUT/manifest.jsonl (one line per scene: its shard and member names).
Resumable: a rerun renders only the shards that are not finished. Exits 1 when a scene
could not be rendered (it is named in the manifest and the summary). Without --ray, and
without RAY_ADDRESS, a local Ray cluster on this machine.
"""

from __future__ import annotations

import sys

from glraster.cli import exit_codes
from glraster.cli.errors import describe
from glraster.cli.commands import add_backend_argument, add_command, comma_list
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFile, OutputFolder


def register(subparsers) -> None:
    p = add_command(subparsers, "batch", __doc__)
    p.add_argument("input", metavar="IN", nargs="?", default=None,
                   help="folder of scene files, .txt list, or .json views file")
    p.add_argument("output", action=OutputFolder, metavar="OUT", nargs="?", default=None,
                   help="output folder (shards, manifest.jsonl)")
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)")
    add_backend_argument(p)
    p.add_argument("--driver", default=None, metavar="NAME",
                   help="render on nodes advertising driver:NAME, selected by its environment "
                        "(llvmpipe, softpipe, ...; default: each node's own GL)")
    p.add_argument("--outputs", default=None, type=comma_list, metavar="LIST",
                   help="comma-separated subset of persp,screen,depth,tri_id "
                        "(default: each scene's outputs)")
    p.add_argument("--shard-size", type=int, default=None, metavar="N",
                   help="scenes per shard (default 64)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="GL worker actors (default: the CPUs of the nodes that can run them)")
    p.add_argument("--bench", action="store_true",
                   help="measure instead: 2 actors against 2 in-process loops of rasterize "
                        "(throughput ratio), per-task overhead at 64^2 and 1024^2, head cost "
                        "per task, and .npz against Parquet shards (no IN/OUT)")
    p.add_argument("--json", action=OutputFile,
                   default=None, metavar="FILE", help="with --bench: write the figures")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.bench:
        return _bench(args)
    if not args.input or not args.output:
        print("glraster batch: IN and OUT are required (or --bench)", file=sys.stderr)
        return exit_codes.USAGE
    outputs = None
    try:
        if args.outputs:
            from glraster.validate import outputs as check_outputs

            outputs = check_outputs([o.strip() for o in args.outputs.split(",") if o.strip()])
        from glraster.cluster import dataset, inputs

        inputs.list_items(args.input)  # a bad IN is a usage error before Ray starts
        shard_size = dataset.DEFAULT_SHARD_SIZE if args.shard_size is None else args.shard_size
        if shard_size < 1:
            raise ArgumentError(
                "--shard-size", f"--shard-size must be a positive integer, got {shard_size}")
        if args.workers is not None and args.workers < 1:
            raise ArgumentError(
                "--workers", f"--workers must be a positive integer, got {args.workers}")
    except ValueError as exc:
        print(f"glraster batch: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.USAGE
    from glraster.cli.commands.check import Progress

    try:
        summary = dataset.render_dataset(args.input, args.output, address=args.ray,
                                         driver=args.driver, shard_size=shard_size,
                                         outputs=outputs, workers=args.workers,
                                         backend=args.backend, progress=Progress())
    except ValueError as exc:
        print(f"glraster batch: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.USAGE
    except RuntimeError as exc:  # GL came up on no worker
        print(f"glraster batch: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    print(summary.text())
    return exit_codes.OK if summary.ok else exit_codes.FAIL


def _bench(args) -> int:
    import json

    from glraster.cluster import bench

    figures = bench.run(address=args.ray, backend=args.backend, progress=print)
    print(bench.format_figures(figures))
    if args.json:
        from pathlib import Path

        from glraster.io.atomic import atomic_write

        with atomic_write(Path(args.json)) as tmp:
            Path(tmp).write_text(json.dumps(figures, indent=2))
        print(f"figures: {args.json}")
    return exit_codes.OK
