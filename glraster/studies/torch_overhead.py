"""Per-call overhead of the glraster.torch wrappers: forward + backward of each op through
``glraster.torch`` minus the same op's core forward + backward (``Op.core(float32)``, from
``glraster.diff.ops``) on the same checked inputs, for two source trees side by side.

    glraster study torch-overhead --before-commit f8b5c47 --sizes 64 1024 --rounds 5

``--before`` is a checkout of the older tree (``--before-commit`` makes a temporary git
worktree of that commit instead and removes it afterwards); ``--after`` is this tree. Each
round runs one fresh interpreter per tree, in alternating order (interleaved A/B); a
worker times ``--calls`` alternating (wrapper, core) pairs per op and size, and its
overhead is the median of the pairs' differences: the wrapper's tensor checks, validation,
NumPy and torch conversions and autograd's bookkeeping (gradients by
``torch.autograd.grad``, so nothing accumulates into the leaves' ``.grad``). The table
gives the median and range over rounds and before / after. Scene: a 16 x 16 grid of
quads (512 triangles, w from 1 to 1.8) over 80% of an N x N float32 image on OpenGL, 3
attributes, a 256² RGB texture (linear), antialias with a prebuilt topology hash; every
float input wants its gradient. Timings on a shared machine are noisy: read the ratio
and the ranges, not single milliseconds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
OPS = ("rasterize", "interpolate", "texture", "antialias")


def _scene(quads: int = 16):
    xs = np.linspace(-0.8, 0.8, quads + 1)
    x, y = np.meshgrid(xs, xs)
    w = 1.0 + 0.5 * (x + 0.8)
    pos = np.stack([x * w, y * w, 0.2 * x * w, w], -1).reshape(-1, 4).astype(np.float32)
    v = np.arange((quads + 1) ** 2).reshape(quads + 1, quads + 1)
    a, b, c, d = v[:-1, :-1], v[:-1, 1:], v[1:, :-1], v[1:, 1:]
    tri = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                          np.stack([a, d, c], -1).reshape(-1, 3)]).astype(np.int32)
    uv = np.stack([(x + 0.8) / 1.6, (y + 0.8) / 1.6], -1).reshape(-1, 2).astype(np.float32)
    return pos, tri, uv


def _cases(size: int, glctx):
    """op -> (wrapper step, core step), both forward + backward of the same inputs."""
    import torch

    import glraster.torch as dr
    from glraster.diff import ops

    rng = np.random.default_rng(0)
    pos, tri, uv_attr = _scene()
    res = (size, size)
    tri_t = torch.from_numpy(tri)
    with torch.no_grad():
        rast, _ = dr.rasterize(glctx, torch.from_numpy(pos), tri_t, res)
        uv, _ = dr.interpolate(torch.from_numpy(uv_attr), rast, tri_t, glctx=glctx)
    leaf = lambda a: torch.tensor(a, requires_grad=True)  # noqa: E731
    like = lambda shape: rng.uniform(0.5, 1.0, shape).astype(np.float32)  # noqa: E731
    attr = rng.uniform(0, 1, (len(pos), 3)).astype(np.float32)
    tex = rng.uniform(0, 1, (1, 256, 256, 3)).astype(np.float32)
    color = like(rast.shape[:3] + (3,))
    th = dr.antialias_construct_topology_hash(tri_t)
    image = lambda c: like(rast.shape[:3] + (c,))  # noqa: E731
    specs = {
        "rasterize": (ops.RASTERIZE, [pos], dict(tri=tri, resolution=res),
                      [image(4), image(4)],
                      lambda t: dr.rasterize(glctx, t[0], tri_t, res)),
        "interpolate": (ops.INTERPOLATE, [attr, rast.numpy()], dict(tri=tri),
                        [image(3), image(0)],
                        lambda t: dr.interpolate(t[0], t[1], tri_t, glctx=glctx)),
        "texture": (ops.TEXTURE, [tex, uv.numpy()], dict(filter_mode="linear"), [image(3)],
                    lambda t: (dr.texture(t[0], t[1], filter_mode="linear", glctx=glctx),)),
        "antialias": (ops.ANTIALIAS, [color, rast.numpy(), pos],
                      dict(tri=tri, topology_hash=th), [image(3)],
                      lambda t: (dr.antialias(t[0], t[1].detach(), t[2], tri_t, th,
                                              glctx=glctx),)),
    }
    cases = {}
    for name, (op, inputs, params, grads, call) in specs.items():
        tensors = [leaf(a) for a in inputs]
        grads_t = [torch.from_numpy(g) for g in grads]
        arrays, checked = op.check(*inputs, **params, ctx=glctx.context)
        core = op.core(np.float32)

        def wrapper(call=call, tensors=tensors, grads_t=grads_t):
            outs = call(tensors)   # autograd.grad: no .grad accumulated into the leaves
            torch.autograd.grad([o for o, g in zip(outs, grads_t) if g.numel()], tensors,
                                [g for g in grads_t if g.numel()], allow_unused=True)

        def bare(core=core, arrays=arrays, checked=checked, grads=grads):
            _, saved = core.forward(*arrays, **checked)
            core.backward(saved, *grads)

        cases[name] = (wrapper, bare)
    return cases


def worker(sizes, calls: int) -> dict:
    """{op: {size: [wrapper s, core s, overhead s]}}: medians over ``calls`` alternating
    (wrapper, core) pairs, the overhead that of each pair's difference."""
    import glraster.torch as dr

    glctx = dr.RasterizeGLContext()
    out = {name: {} for name in OPS}
    for size in sizes:
        for name, (wrapper, bare) in _cases(size, glctx).items():
            wrapper(), bare()                      # warm: shaders compiled, buffers sized
            times = ([], [])
            for _ in range(calls):
                for k, fn in enumerate((wrapper, bare)):
                    start = time.perf_counter()
                    fn()
                    times[k].append(time.perf_counter() - start)
            out[name][str(size)] = [statistics.median(t) for t in times] + [
                statistics.median(a - b for a, b in zip(*times))]
    return out


def _run_worker(tree: Path, sizes, calls: int) -> dict:
    from glraster.studies import revision  # here: the worker runs this file in its tree

    env = revision.tree_environment(tree)
    done = subprocess.run([sys.executable, str(HERE), "--worker", "--calls", str(calls),
                           "--sizes", *map(str, sizes)], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(f"worker in {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(before: Path, after: Path, sizes, rounds: int, calls: int) -> list[dict]:
    """Rows (op, size, core ms, overheads ms: median and range over rounds, ratio)."""
    trees = {"before": before, "after": after}
    results = {name: [] for name in trees}
    for r in range(rounds):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            results[name].append(_run_worker(trees[name], sizes, calls))
    rows = []
    for op in OPS:
        for size in map(str, sizes):
            row = {"op": op, "size": int(size)}
            for name, runs in results.items():
                row[f"core_{name}_ms"] = 1e3 * statistics.median(x[op][size][1] for x in runs)
                overheads = [1e3 * x[op][size][2] for x in runs]
                row[f"overhead_{name}_ms"] = statistics.median(overheads)
                row[f"range_{name}_ms"] = (min(overheads), max(overheads))
            before, after = row["overhead_before_ms"], row["overhead_after_ms"]
            row["ratio"] = before / after if before > 0 and after > 0 else None
            rows.append(row)
    return rows


def main(argv=None) -> int:
    # a plain parser, not studies.registry's: the workers run this file against older
    # trees, which may not have the registry
    parser = argparse.ArgumentParser(prog="glraster study torch-overhead",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="a checkout of the older tree")
    parser.add_argument("--before-commit", help="or: a commit to check out as the older tree")
    parser.add_argument("--after", type=Path, default=HERE.parents[2])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 1024])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=9)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.sizes, args.calls)))
        return 0
    if (args.before is None) == (args.before_commit is None):
        parser.error("give one of --before PATH or --before-commit COMMIT")
    for option, value in (("sizes", min(args.sizes)), ("rounds", args.rounds),
                          ("calls", args.calls)):
        if value < 1:
            parser.error(f"--{option} must be at least 1, got {value}")
    with tempfile.TemporaryDirectory() as tmp:
        before = args.before
        if before is None:
            before = Path(tmp) / "before"
            subprocess.run(["git", "-C", str(args.after), "worktree", "add", "--detach",
                            "--quiet", str(before), args.before_commit], check=True)
        try:
            rows = compare(before.resolve(), args.after.resolve(), args.sizes, args.rounds,
                           args.calls)
        finally:
            if args.before is None:
                subprocess.run(["git", "-C", str(args.after), "worktree", "remove", "--force",
                                str(before)], check=False)
    print(f"medians of {args.rounds} rounds (one fresh interpreter per tree and round, "
          f"alternating), each the median of {args.calls} (wrapper - core) pairs [range over "
          "rounds]; float32 on OpenGL")
    print("| op | size | core ms | overhead before ms | overhead after ms | before / after |")
    print("|---|---|---|---|---|---|")
    span = lambda r: f"{r[0]:.2f} .. {r[1]:.2f}"  # noqa: E731
    for row in rows:
        ratio = "noise" if row["ratio"] is None else f"{row['ratio']:.2f}"
        print(f"| {row['op']} | {row['size']}² | {row['core_after_ms']:.1f} | "
              f"{row['overhead_before_ms']:.2f} [{span(row['range_before_ms'])}] | "
              f"{row['overhead_after_ms']:.2f} [{span(row['range_after_ms'])}] | {ratio} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
