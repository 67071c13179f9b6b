"""Iterations per second of the glraster.torch fits, and a mipmapped texture call on a
texture that does not change, for two source trees in one run (interleaved A/B).

    glraster study fit-iterations-ab --before /path/to/older/checkout --rounds 5

One interpreter per tree, warmed up once; each round asks them in alternating order for
each case in turn (interleaved A/B, so both see the same load): the cube fit
(``fit_cube``: 4 views, rasterize -> interpolate -> antialias, Adam) at 4x4 and 16x16,
the pose fit (``fit_pose``, 2 restarts) at ``--size`` (256), and forward + backward of a
linear-mipmap-linear ``texture`` call at that size on a constant RGBA texture of that
size (``mip=None``, gradients to uv and uv_da). The table gives the median over rounds,
the range, after / before of the medians and the median of each round's after / before
(paired: both trees measured back to back). float32 on OpenGL, one torch thread (as
``glraster fit``). Timings on a shared machine are noisy: read the ratio and the ranges.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
CASES = ("cube 4x4", "cube 16x16", "pose", "texture mip=None, constant tex")


def cases(iterations: int, size: int) -> dict:
    """{case: (run(n), n)}: each run does n iterations (or calls), warmed up once."""
    import torch

    import glraster.torch as dr
    from glraster.torch.fitting.cube import fit_cube
    from glraster.torch.fitting.pose import fit_pose

    torch.set_num_threads(1)
    glctx = dr.RasterizeGLContext()
    tex = torch.rand(1, size, size, 4, generator=torch.Generator().manual_seed(0))
    s = (torch.arange(size) + 0.5) / size
    uv = torch.stack(torch.meshgrid(s, s * 0.7, indexing="xy"), -1)[None].contiguous()
    uv_da = torch.tensor([0.9, 0.1, 0.2, 1.7]).expand(1, size, size, 4) / size
    uv.requires_grad_()
    uv_da = uv_da.contiguous().requires_grad_()

    def texture_calls(n):
        for _ in range(n):
            out = dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear", glctx=glctx)
            out.sum().backward()

    few = max(iterations // 5, 4)
    return {"cube 4x4": (lambda n: fit_cube(glctx, 4, 0, iterations=n), iterations),
            "cube 16x16": (lambda n: fit_cube(glctx, 16, 0, iterations=n), iterations),
            "pose": (lambda n: fit_pose(glctx, 0, resolution=size, restarts=2,
                                                iterations=n, jumps=()), few),
            CASES[3]: (texture_calls, few)}


def serve(iterations: int, size: int) -> None:
    """Read case names from stdin, one a line; answer each with its rate per second."""
    table = cases(iterations, size)
    for run, n in table.values():
        run(max(n // 10, 2))                          # warm: shaders, buffers
    print("ready", flush=True)
    for line in sys.stdin:
        run, n = table[line.strip()]
        start = time.perf_counter()
        run(n)
        print(n / (time.perf_counter() - start), flush=True)


def _start(tree: Path, iterations: int, size: int) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(tree))
    proc = subprocess.Popen([sys.executable, str(HERE), "--worker", "--iterations",
                             str(iterations), "--size", str(size)], cwd=tree, env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    if proc.stdout.readline().strip() != "ready":
        raise RuntimeError(f"the worker in {tree} did not start")
    return proc


def _ask(proc: subprocess.Popen, case: str) -> float:
    proc.stdin.write(case + "\n")
    proc.stdin.flush()
    return float(proc.stdout.readline())


def main(argv=None) -> int:
    # a plain parser, not studies.registry's: the workers run this file against older
    # trees, which may not have the registry
    parser = argparse.ArgumentParser(prog="glraster study fit-iterations-ab",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="the older checkout (required)")
    parser.add_argument("--after", type=Path, default=HERE.parents[2])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--size", type=int, default=256, help="pose and texture image size")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        serve(args.iterations, args.size)
        return 0
    if args.before is None:
        parser.error("--before PATH (a checkout of the older tree) is required")
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    workers = {name: _start(tree, args.iterations, args.size) for name, tree in trees.items()}
    runs = {name: [{} for _ in range(args.rounds)] for name in trees}
    try:
        for r in range(args.rounds):
            for case in CASES:
                for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
                    runs[name][r][case] = _ask(workers[name], case)
    finally:
        for proc in workers.values():
            proc.stdin.close()
            proc.wait(timeout=60)
    print(f"medians of {args.rounds} rounds (one warm interpreter per tree, the two "
          "alternating case by case) [range]; iterations (texture: calls) per second")
    print("| case | before /s | after /s | after / before | median of the rounds' ratios |")
    print("|---|---|---|---|---|")
    for case in CASES:
        cells = []
        for name in trees:
            values = [run[case] for run in runs[name]]
            cells.append((statistics.median(values), min(values), max(values)))
        (b, b0, b1), (a, a0, a1) = cells
        paired = statistics.median(r_after[case] / r_before[case]
                                   for r_before, r_after in zip(*runs.values()))
        label = f"{case} {args.size}²" if case in CASES[2:] else case
        print(f"| {label} | {b:.1f} [{b0:.1f} .. {b1:.1f}] | {a:.1f} [{a0:.1f} .. {a1:.1f}] "
              f"| {a / b:.2f} | {paired:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
