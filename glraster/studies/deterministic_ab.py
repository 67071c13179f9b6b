"""A/B timing of the deterministic backward of rasterize and interpolate against another
checkout of glraster (e.g. the commit before a change), in one run.

Each checkout runs in its own worker process (its own GL context) on the cells of
``glraster bench-diff`` (:class:`glraster.studies.diff_bench._Cell`'s inputs: the terrain
scene, random upstream gradients); the driver asks the workers for one round in turn
(A B A B ..., one warm-up round each), so slow phases of a shared machine hit both sides.
Per checkout and round it times the rasterize forward with rast_db, the rasterize backward
with atomics and deterministic, and the interpolate core backward (diff_attrs="all") with
atomics and deterministic, and reports the medians over rounds of the per-round ratios
``backward_atomic_over_forward``, ``backward_deterministic_over_forward``,
``rasterize_deterministic_over_atomic`` and ``interpolate_deterministic_over_atomic``
(the bench-diff cells of the same names).

    glraster study deterministic-ab --base /path/to/other/checkout \\
        --sizes 256 1024 --counts 1000 20000 --rounds 7
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

CALLS = ("forward_db", "backward_atomic", "backward_deterministic",
         "interp_atomic", "interp_deterministic")


def worker() -> None:
    """Serve rounds on stdin/stdout: a line "size count" builds the cell; "round" times
    each call once and answers a JSON line of seconds."""
    from glraster.diff import interpolate as core_interpolate
    from glraster.diff import rasterize as core_rasterize
    from glraster.diff.ops import INTERPOLATE, RASTERIZE
    from glraster.gpu.context import default_context
    from glraster.studies.bench import make_bench_scene

    ctx = default_context()
    calls = {}
    for line in sys.stdin:
        words = line.split()
        if words[0] == "cell":
            size, count = int(words[1]), int(words[2])
            scene = make_bench_scene("terrain", count)
            rng = np.random.default_rng(0)
            (pos,), params = RASTERIZE.check(scene.pos, tri=scene.faces,
                                             resolution=(size, size), ctx=ctx)
            (rast, rast_db), saved = core_rasterize.forward(pos, **params)
            grad_rast = rng.standard_normal(rast.shape).astype(np.float32)
            grad_db = rng.standard_normal(rast.shape).astype(np.float32)
            attr = rng.standard_normal((len(scene.pos), 4)).astype(np.float32)
            g_out = rng.standard_normal(rast.shape[:3] + (4,)).astype(np.float32)
            g_da = rng.standard_normal(rast.shape[:3] + (8,)).astype(np.float32)
            _, isaved = INTERPOLATE.forward(attr, rast, rast_db, tri=scene.faces,
                                            diff_attrs="all", ctx=ctx)
            calls = {
                "forward_db": lambda: core_rasterize.forward(pos, **params),
                "backward_atomic": lambda: core_rasterize.backward(saved, grad_rast, grad_db),
                "backward_deterministic": lambda: core_rasterize.backward(
                    saved, grad_rast, grad_db, deterministic=True),
                "interp_atomic": lambda: core_interpolate.backward(isaved, g_out, g_da),
                "interp_deterministic": lambda: core_interpolate.backward(
                    isaved, g_out, g_da, deterministic=True),
            }
            print("{}", flush=True)
        elif words[0] == "round":
            out = {}
            for name, fn in calls.items():
                start = time.perf_counter()
                fn()
                out[name] = time.perf_counter() - start
            print(json.dumps(out), flush=True)


def _start(checkout: str) -> subprocess.Popen:
    from glraster.studies import revision  # here: the worker runs this file in its tree

    env = revision.tree_environment(os.path.abspath(checkout))
    return subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=env, cwd=os.path.abspath(checkout))


def _ask(proc: subprocess.Popen, line: str) -> dict:
    proc.stdin.write(line + "\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def main(argv=None) -> int:
    # a plain parser, not studies.registry's: the workers run this file against older
    # trees, which may not have the registry
    parser = argparse.ArgumentParser(prog="glraster study deterministic-ab",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--base", help="the other checkout (A)")
    parser.add_argument("--new", default=os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__)))), help="this checkout (B), default: the one holding this "
                                          "file")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--counts", type=int, nargs="+", default=[1000, 20000])
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args(argv)
    if args.worker:
        worker()
        return 0
    if not args.base:
        parser.error("--base is required")
    sides = {"base": _start(args.base), "new": _start(args.new)}
    print("| cell | side | fwd ms | atomic bwd ms | det bwd ms | atomic / fwd | det / fwd "
          "| det / atomic | interp det / atomic |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes:
        for count in args.counts:
            times = {side: {c: [] for c in CALLS} for side in sides}
            for proc in sides.values():
                _ask(proc, f"cell {size} {count}")
                _ask(proc, "round")                     # warm-up
            for _ in range(args.rounds):
                for side, proc in sides.items():
                    for name, seconds in _ask(proc, "round").items():
                        times[side][name].append(seconds)
            for side, t in times.items():
                t = {k: np.array(v) for k, v in t.items()}
                atomic_fwd = np.median(t["backward_atomic"] / t["forward_db"])
                det_fwd = np.median(t["backward_deterministic"] / t["forward_db"])
                det_atomic = np.median(t["backward_deterministic"] / t["backward_atomic"])
                interp = np.median(t["interp_deterministic"] / t["interp_atomic"])
                print(f"| {size}² {count} | {side} | {np.median(t['forward_db']) * 1e3:.1f} "
                      f"| {np.median(t['backward_atomic']) * 1e3:.1f} "
                      f"| {np.median(t['backward_deterministic']) * 1e3:.1f} "
                      f"| {atomic_fwd:.2f} | {det_fwd:.2f} | {det_atomic:.2f} | {interp:.2f} |",
                      flush=True)
    for proc in sides.values():
        proc.stdin.close()
        proc.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
