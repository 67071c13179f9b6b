"""``glraster.interpolate`` (the Raster adapter over the differentiable interpolate's float64
core) against the plain weighted sum it replaced, ``einsum("nk,nkc->nc", b, corners)`` over
the covered pixels, on the same GPU raster, in one process.

    glraster study interpolate-adapter --sizes 320x240 640x480 --rounds 7

A 48 x 24 torus seen in perspective, rasterized once per size (persp and tri_id, float32);
attributes: the 3 eye-space coordinates and the clip w. The two variants alternate round by
round (interleaved A/B); each round's figure is the median of ``--calls`` calls, and the
table shows the median over rounds, the ratio and the largest difference between the two
results (0: bit-identical float32). Timings on a shared machine are noisy: read the ratio.
"""

from __future__ import annotations

import argparse
import statistics
import timeit

import numpy as np

import glraster as gr
from glraster.geometry import camera as cam
from glraster.geometry import shapes
from glraster.studies.registry import argument_parser


def weighted_sum(attr, raster, tri) -> np.ndarray:
    """sum_k b_k attr[tri[t, k]] / sum_k b_k per covered pixel, in float64, rounded once."""
    covered = raster.tri_id >= 0
    b = raster.persp[covered].astype(np.float64)
    vals = np.einsum("nk,nkc->nc", b, attr[tri[raster.tri_id[covered]]].astype(np.float64))
    out = np.zeros(raster.tri_id.shape + (attr.shape[1],), raster.persp.dtype)
    out[covered] = vals / b.sum(axis=1, keepdims=True)
    return out


def _scene(height: int, width: int, ctx):
    vertices, faces = shapes.torus(1.0, 0.35, 48, 24)
    view = cam.look_at([0.5, 2.2, 2.6], [0, 0, 0])
    pos = cam.project(vertices, None, view, cam.perspective(50.0, width / height, 0.5, 10.0))
    attr = np.c_[vertices @ view[:3, :3].T + view[:3, 3], pos[:, 3]]
    raster = gr.rasterize(pos, faces, (height, width), ctx=ctx, outputs=("persp", "tri_id"))
    return attr, raster, faces


def measure(height: int, width: int, rounds: int, calls: int, ctx) -> dict:
    attr, raster, faces = _scene(height, width, ctx)
    adapter = lambda: gr.interpolate(attr, raster, faces)   # noqa: E731
    plain = lambda: weighted_sum(attr, raster, faces)       # noqa: E731
    diff = float(np.abs(adapter().astype(np.float64) - plain()).max())
    a, b = [], []
    for _ in range(rounds):
        a.append(statistics.median(timeit.repeat(adapter, number=1, repeat=calls)))
        b.append(statistics.median(timeit.repeat(plain, number=1, repeat=calls)))
    return {"size": f"{width}x{height}", "covered": int(raster.mask.sum()),
            "adapter_ms": 1e3 * statistics.median(a), "plain_ms": 1e3 * statistics.median(b),
            "max_diff": diff}


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a size is WIDTHxHEIGHT, got {text!r}") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"a size must be at least 1x1, got {text!r}")
    return height, width


def main(argv=None) -> int:
    parser = argument_parser("interpolate-adapter", __doc__)
    parser.add_argument("--sizes", nargs="+", type=_size, default=[(240, 320), (480, 640)],
                        metavar="WxH")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calls", type=int, default=3)
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.calls < 1:
        parser.error("--rounds and --calls must be at least 1")
    ctx = gr.Context()
    try:
        print("| size | covered pixels | adapter (ms) | plain weighted sum (ms) | ratio | "
              "max difference |")
        print("|---|---|---|---|---|---|")
        for height, width in args.sizes:
            r = measure(height, width, args.rounds, args.calls, ctx)
            print(f"| {r['size']} | {r['covered']} | {r['adapter_ms']:.1f} | "
                  f"{r['plain_ms']:.1f} | {r['adapter_ms'] / r['plain_ms']:.2f} | "
                  f"{r['max_diff']:.3g} |")
    finally:
        ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
