"""Per-call cost of glraster.jax against glraster.torch and the bare cores: rasterize ->
interpolate, forward alone and forward + backward, float32 on OpenGL, in one process.

    glraster study jax-overhead --size 64 --rounds 7 --calls 20

One triangle pair (the scene of tests/torch/scenes.py) at N x N pixels with 3 attributes.
Variants, alternated round by round (interleaved A/B), each round's figure the median of
``--calls`` calls, the table the median over rounds:

- ``cores``: ``glraster.diff.ops`` RASTERIZE and INTERPOLATE cores called directly
  (``core.forward`` / ``core.backward`` on NumPy arrays): no front end at all;
- ``torch``: glraster.torch (autograd);
- ``jax eager``: glraster.jax called op by op (``jax.vjp`` outside jit);
- ``jax jit``: the same function under ``jax.jit(jax.value_and_grad(...))``.

The JAX backward recomputes the forward (the bridge's residuals are the inputs), so
forward + backward costs one more core forward than torch's: the ``cores`` row with
``+ forward`` shows that price. Timings on a shared machine are noisy: read the ratios.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import glraster.jax as jdr
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from glraster.studies.registry import argument_parser

POS = np.array([[-0.80, -0.68, 0.35, 1.00], [1.00, -0.82, 0.52, 1.30],
                [0.13, 0.83, 0.41, 0.70], [1.24, 1.23, 0.62, 1.55]], np.float32)
TRI = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
COLORS = np.random.default_rng(0).uniform(size=(4, 3)).astype(np.float32)


def _median_call(fn, calls: int) -> float:
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def variants(size: int, ctx):
    """name -> (forward, forward + backward) callables."""
    res = (size, size)
    r_core, i_core = RASTERIZE.core(np.float32), INTERPOLATE.core(np.float32)

    def cores(backward: bool, extra_forward: bool = False):
        (rast, db), r_saved = r_core.forward(POS, tri=TRI, resolution=res, ranges=None,
                                             grad_db=False, space="persp", ctx=ctx)
        (out, out_da), i_saved = i_core.forward(COLORS, rast, None, tri=TRI, diff_attrs=None,
                                                ctx=ctx)
        if backward:
            if extra_forward:
                r_core.forward(POS, tri=TRI, resolution=res, ranges=None, grad_db=False,
                               space="persp", ctx=ctx)
                i_core.forward(COLORS, rast, None, tri=TRI, diff_attrs=None, ctx=ctx)
            _, g_rast, _ = i_core.backward(i_saved, np.ones_like(out), None)
            r_core.backward(r_saved, g_rast, None)

    import torch

    import glraster.torch as tdr

    tctx = tdr.RasterizeGLContext(output_db=False, context=ctx)
    tpos, tcol, ttri = torch.tensor(POS, requires_grad=True), torch.tensor(COLORS,
                                                                           requires_grad=True), \
        torch.tensor(TRI)

    def torch_call(backward: bool):
        rast, _ = tdr.rasterize(tctx, tpos, ttri, res)
        out, _ = tdr.interpolate(tcol, rast, ttri, glctx=tctx)
        if backward:
            out.sum().backward()

    jctx = jdr.RasterizeGLContext(output_db=False, context=ctx)

    def loss(p, c):
        rast, _ = jdr.rasterize(jctx, p, TRI, res)
        out, _ = jdr.interpolate(c, rast, TRI, glctx=jctx)
        return jnp.sum(out)

    jpos, jcol = jnp.asarray(POS), jnp.asarray(COLORS)
    grad_jit = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
    loss_jit = jax.jit(loss)

    def jax_eager(backward: bool):
        if backward:
            value, vjp = jax.vjp(loss, jpos, jcol)
            jax.block_until_ready(vjp(jnp.ones_like(value)))
        else:
            jax.block_until_ready(loss(jpos, jcol))

    def jax_jit(backward: bool):
        jax.block_until_ready(grad_jit(jpos, jcol) if backward else loss_jit(jpos, jcol))

    return {
        "cores": (lambda: cores(False), lambda: cores(True)),
        "cores + forward": (lambda: cores(False), lambda: cores(True, extra_forward=True)),
        "torch": (lambda: torch_call(False), lambda: torch_call(True)),
        "jax eager": (lambda: jax_eager(False), lambda: jax_eager(True)),
        "jax jit": (lambda: jax_jit(False), lambda: jax_jit(True)),
    }


def main(argv=None) -> int:
    parser = argument_parser("jax-overhead", __doc__)
    parser.add_argument("--size", type=int, default=64, help="image size in pixels (64)")
    parser.add_argument("--rounds", type=int, default=7, help="interleaved rounds (7)")
    parser.add_argument("--calls", type=int, default=20, help="calls per round (20)")
    parser.add_argument("--backend", default=None, help="OpenGL backend (auto)")
    args = parser.parse_args(argv)
    for option in ("size", "rounds", "calls"):
        if getattr(args, option) < 1:
            parser.error(f"--{option} must be at least 1, got {getattr(args, option)}")
    from glraster.gpu.context import Context

    ctx = Context(backend=args.backend)
    table = variants(args.size, ctx)
    for forward, both in table.values():
        forward(), both()                          # warm: shaders, buffers, XLA compiled
    results = {name: ([], []) for name in table}
    for r in range(args.rounds):
        order = list(table) if r % 2 == 0 else list(table)[::-1]
        for name in order:
            for k in range(2):
                results[name][k].append(_median_call(table[name][k], args.calls))
    core_f, core_b = (statistics.median(v) for v in results["cores"])
    print(f"rasterize -> interpolate at {args.size}x{args.size}, float32, {ctx.renderer}; "
          f"median of {args.rounds} rounds x {args.calls} calls")
    print(f"{'variant':<16} {'forward ms':>11} {'overhead':>9} {'fwd+bwd ms':>11} "
          f"{'overhead':>9}")
    for name, (f, b) in results.items():
        f, b = statistics.median(f), statistics.median(b)
        print(f"{name:<16} {1e3 * f:11.3f} {1e3 * (f - core_f):9.3f} {1e3 * b:11.3f} "
              f"{1e3 * (b - core_b):9.3f}")
    ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
