"""Timing of glraster.diff.antialias (GPU, forward + backward) against its float64 reference
(glraster.diff.antialias_reference) at 256², 512² and 1024² (docs/differentiable.md,
"Antialias").

    glraster study diff-antialias-figures [--repeat N]
"""

from __future__ import annotations

import functools

import numpy as np

import glraster as gr
from glraster.diff import antialias as gaa
from glraster.diff import antialias_reference as aar
from glraster.diff.ops import ANTIALIAS, INTERPOLATE, RASTERIZE
from glraster.geometry import camera, shapes
from glraster.studies.registry import argument_parser
from glraster.studies.timing import best_seconds as best


def scene(size: int, level: int = 4):
    verts, faces = shapes.icosphere(level)
    mvp = camera.perspective(40, 1.0, 0.5, 10) @ camera.look_at((0.3, 0.4, 3.0), (0, 0, 0))
    pos = (np.concatenate([verts, np.ones((len(verts), 1))], 1) @ mvp.T).astype(np.float32)
    colors = np.random.default_rng(0).uniform(0, 1, (len(verts), 3)).astype(np.float32)
    return pos, faces.astype(np.int32), colors


def reference(color, rast, pos, tri, th, g):
    _, saved = ANTIALIAS.forward(color, rast, pos, tri=tri, topology_hash=th)
    aar.backward(saved, g)


def main(argv=None):
    parser = argument_parser("diff-antialias-figures", __doc__)
    parser.add_argument("--repeat", type=int, default=5, help="timed calls; the best is shown")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be at least 1, got {args.repeat}")
    ctx = gr.Context()
    print(f"renderer: {ctx.renderer}")
    print("| frame | triangles | blended pairs | GPU fwd ms | GPU bwd ms (atomic) | "
          "GPU bwd ms (deterministic) | GPU fwd+bwd ms | float64 fwd+bwd ms | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in (256, 512, 1024):
        pos, tri, colors = scene(size)
        (rast, _), _ = RASTERIZE.forward(np.asarray(pos, np.float32), tri=tri,
                                         resolution=(size, size), ctx=ctx)
        (col, _), _ = INTERPOLATE.forward(np.asarray(colors, np.float32), rast, tri=tri,
                                          ctx=ctx)
        g = np.random.default_rng(1).normal(size=col.shape).astype(np.float32)
        th = gaa.antialias_construct_topology_hash(tri)
        th.table()
        _, saved = ANTIALIAS.forward(col, rast, pos, tri=tri, topology_hash=th, ctx=ctx)
        gaa.backward(saved, g)
        fwd = best(functools.partial(ANTIALIAS.forward, col, rast, pos, tri=tri,
                                     topology_hash=th, ctx=ctx), args.repeat)
        bwd = best(functools.partial(gaa.backward, saved, g), args.repeat)
        bwd_det = best(functools.partial(gaa.backward, saved, g, deterministic=True),
                       args.repeat)
        r64, c64, p64 = rast.astype(np.float64), col.astype(np.float64), pos.astype(np.float64)
        ref = best(functools.partial(reference, c64, r64, p64, tri, th, g),
                   max(1, args.repeat // 2))
        _, s = ANTIALIAS.forward(c64, r64, p64, tri=tri, topology_hash=th)
        both = fwd + bwd
        print(f"| {size}² | {len(tri)} | {len(s.pairs.tau)} | {fwd * 1e3:.1f} | {bwd * 1e3:.1f} | "
              f"{bwd_det * 1e3:.1f} | {both * 1e3:.1f} | {ref * 1e3:.0f} | {ref / both:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
