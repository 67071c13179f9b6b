"""Iterations per second of the glraster.torch fits, and a mipmapped texture call on a
texture that does not change, for two source trees in one run (interleaved A/B).

    python benchmarks/fit_iterations_ab.py --before /path/to/older/checkout --rounds 5

Each round runs one fresh interpreter per tree, in alternating order; a worker times, after
a warm-up, the cube fit (``fit_cube``: 4 views, rasterize -> interpolate -> antialias,
Adam) at 4x4 and 16x16, the pose fit (``fit_pose``, 2 restarts) at 256x256, and forward +
backward of a linear-mipmap-linear ``texture`` call at 256x256 on a constant 256x256 RGBA
texture (``mip=None``, gradients to uv and uv_da). The table gives the median over rounds,
the range, and after / before. float32 on OpenGL, one torch thread (as ``glraster fit``).
Timings on a shared machine are noisy: read the ratio and the ranges.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
CASES = ("cube 4x4", "cube 16x16", "pose 256x256", "texture 256² mip=None, constant tex")


def worker(iterations: int) -> dict:
    """{case: iterations (or calls) per second}."""
    import torch

    import glraster.torch as dr
    from glraster.torch.fitting.cube import fit_cube
    from glraster.torch.fitting.pose import fit_pose

    torch.set_num_threads(1)
    glctx = dr.RasterizeGLContext()
    rate = {}

    def timed(name, fn, count):
        fn(max(count // 10, 2))                       # warm: shaders, buffers
        start = time.perf_counter()
        fn(count)
        rate[name] = count / (time.perf_counter() - start)

    timed("cube 4x4", lambda n: fit_cube(glctx, 4, 0, iterations=n), iterations)
    timed("cube 16x16", lambda n: fit_cube(glctx, 16, 0, iterations=n), iterations)
    timed("pose 256x256", lambda n: fit_pose(glctx, 0, resolution=256, restarts=2,
                                             iterations=n, jumps=()), max(iterations // 5, 4))
    size = 256
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

    timed("texture 256² mip=None, constant tex", texture_calls, max(iterations // 5, 4))
    return rate


def _run_worker(tree: Path, iterations: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    done = subprocess.run([sys.executable, str(HERE), "--worker", "--iterations",
                           str(iterations)], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(f"worker in {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="the older checkout (required)")
    parser.add_argument("--after", type=Path, default=HERE.parents[1])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.iterations)))
        return 0
    if args.before is None:
        parser.error("--before PATH (a checkout of the older tree) is required")
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    runs = {name: [] for name in trees}
    for r in range(args.rounds):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            runs[name].append(_run_worker(trees[name], args.iterations))
    print(f"medians of {args.rounds} rounds (one fresh interpreter per tree and round, "
          "alternating) [range]; iterations (texture: calls) per second")
    print("| case | before /s | after /s | after / before |")
    print("|---|---|---|---|")
    for case in CASES:
        cells = []
        for name in trees:
            values = [run[case] for run in runs[name]]
            cells.append((statistics.median(values), min(values), max(values)))
        (b, b0, b1), (a, a0, a1) = cells
        print(f"| {case} | {b:.1f} [{b0:.1f} .. {b1:.1f}] | {a:.1f} [{a0:.1f} .. {a1:.1f}] "
              f"| {a / b:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
