"""Multisampling cost, in one run: ``samples=1`` against the previous commit's rasterize
(the single-sample path must be no slower), and S samples against 1.

    glraster study multisample-cost --base /path/to/checkout/of/the/previous/commit

Each measurement is a fresh interpreter (``PYTHONPATH`` = one source tree) that warms up
and prints the median of ``--calls`` calls of ``glraster.rasterize`` on the benchmark
terrain; trees and sample counts alternate round by round (interleaved A/B) and the
medians over ``--rounds`` rounds are compared. Timings on a shared machine are noisy:
read the ratio, not the milliseconds.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

from glraster.studies.registry import argument_parser

# the source tree this module is in (the "samples=" runs import glraster from it)
TREE = Path(__file__).resolve().parents[2]

TIMER = r"""
import json, sys, time
import numpy as np
import glraster as gr
from glraster.studies.bench import make_bench_scene
samples, calls, height, width, count = map(int, sys.argv[1:6])
scene = make_bench_scene("terrain", count)
ctx = gr.Context()
kwargs = {} if samples == 1 and sys.argv[6] == "plain" else {"samples": samples}
for _ in range(3):
    gr.rasterize(scene.pos, scene.faces, (height, width), ctx=ctx, **kwargs)
times = []
for _ in range(calls):
    start = time.perf_counter()
    gr.rasterize(scene.pos, scene.faces, (height, width), ctx=ctx, **kwargs)
    times.append(time.perf_counter() - start)
print(json.dumps(sorted(times)[len(times) // 2]))
"""


def measure(tree: Path, samples: int, args, plain: bool = False) -> float:
    from glraster.studies import revision  # here: the worker runs this file in its tree

    env = revision.tree_environment(tree)
    out = subprocess.run(
        [sys.executable, "-c", TIMER, str(samples), str(args.calls), str(args.size),
         str(args.size), str(args.triangles), "plain" if plain else "samples"],
        env=env, check=True, capture_output=True, text=True, cwd=str(tree))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argument_parser("multisample-cost", __doc__)
    parser.add_argument("--base", type=Path, required=True,
                        help="a checkout of the commit before multisampling")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=15)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--triangles", type=int, default=20000)
    args = parser.parse_args(argv)
    if not (args.base / "glraster" / "__init__.py").is_file():
        parser.error(f"--base must be a glraster source tree (with glraster/__init__.py), "
                     f"got {str(args.base)!r}")
    for name in ("rounds", "calls", "size", "triangles"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    import glraster as gr
    counts = [s for s in gr.Context().sample_counts if s > 1]
    runs = {"base": [], "samples=1": [], **{f"samples={s}": [] for s in counts}}
    for number in range(args.rounds):
        order = [("base", args.base, 1, True), ("samples=1", TREE, 1, False)]
        order += [(f"samples={s}", TREE, s, False) for s in counts]
        if number % 2:
            order.reverse()
        for name, tree, samples, plain in order:
            runs[name].append(measure(tree, samples, args, plain))
    median = {name: statistics.median(times) for name, times in runs.items()}
    print(f"terrain, {args.triangles} triangles, {args.size}x{args.size}, all outputs; "
          f"median of {args.rounds} interleaved rounds x {args.calls} calls (shared machine)")
    for name, value in median.items():
        # the ratio of each round's pair, then their median: the load of a round cancels
        paired = statistics.median(a / b for a, b in zip(runs[name], runs["base"]))
        print(f"  {name:11s} {1e3 * value:8.2f} ms   ratio to base {value / median['base']:.3f}"
              f"   per-round ratio median {paired:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
