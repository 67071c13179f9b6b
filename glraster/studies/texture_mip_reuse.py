"""Forward + backward of a linear-mipmap-linear ``glraster.torch.texture`` call with the
pyramid built in the call (``mip=None``) against a pyramid built once by
``texture_construct_mip`` (``mip=``), in one process.

    glraster study texture-mip-reuse --sizes 256 1024 --rounds 7 --calls 5

An N x N image of an N x N RGBA texture seen in perspective (levels ~0 .. 3, wrap), float32
on OpenGL, gradients to uv and uv_da (a constant texture: what texture_construct_mip is
for) and, in a second row, to tex as well. The two variants alternate round by round
(interleaved A/B); each round's figure is the median of ``--calls`` calls, and the table
shows the median over rounds and the ratio. Timings on a shared machine are noisy: read
the ratio, not the milliseconds.
"""

from __future__ import annotations

import statistics

import torch

import glraster.torch as dr
from glraster.studies.registry import argument_parser
from glraster.studies.timing import median_seconds
from glraster.studies.torch_texture_baseline import perspective_inputs


def measure(size: int, tex_grad: bool, rounds: int, calls: int, glctx):
    tex, uv, uv_da = perspective_inputs(size)
    tex.requires_grad_(tex_grad)
    uv.requires_grad_()
    uv_da.requires_grad_()
    mip = dr.texture_construct_mip(tex, glctx=glctx)
    build = median_seconds(lambda: dr.texture_construct_mip(tex, glctx=glctx), calls)

    def step(m):
        out = dr.texture(tex, uv, uv_da, mip=m, filter_mode="linear-mipmap-linear",
                         glctx=glctx)
        out.sum().backward()

    variants = {"built in the call": lambda: step(None), "texture_construct_mip": lambda: step(mip)}
    for fn in variants.values():
        fn()                                       # warm: shaders compiled, buffers sized
    results = {name: [] for name in variants}
    for r in range(rounds):
        order = list(variants) if r % 2 == 0 else list(variants)[::-1]
        for name in order:
            results[name].append(median_seconds(variants[name], calls))
    return {name: statistics.median(v) for name, v in results.items()}, build


def main(argv=None) -> int:
    parser = argument_parser("texture-mip-reuse", __doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calls", type=int, default=5)
    args = parser.parse_args(argv)
    for size in args.sizes:
        if size < 2 or size & (size - 1):
            parser.error(f"--sizes must be powers of two >= 2, got {size}")
    for name in ("rounds", "calls"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    glctx = dr.RasterizeGLContext()
    print(f"renderer: {glctx.context.renderer}; torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads; medians of {args.rounds} interleaved rounds "
          f"of {args.calls} calls")
    print("| size | gradients to | mip=None ms | mip=texture_construct_mip ms | ratio | "
          "texture_construct_mip ms |")
    print("|---|---|---|---|---|---|")
    for size in args.sizes:
        for tex_grad in (False, True):
            times, build = measure(size, tex_grad, args.rounds, args.calls, glctx)
            a, b = times["built in the call"], times["texture_construct_mip"]
            print(f"| {size}² | {'tex, uv, uv_da' if tex_grad else 'uv, uv_da'} | "
                  f"{1e3 * a:.1f} | {1e3 * b:.1f} | {a / b:.2f} | {1e3 * build:.1f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
