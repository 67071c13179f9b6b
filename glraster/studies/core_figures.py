"""Measure the core figures quoted in README.md: coverage and value error of the GPU
against the float64 reference on random triangles at 256x256 (``--size``), on every backend, and the
tolerance model's calibration (worst error / bound with C = 1).

    glraster study core-figures [--backend egl|osmesa] [--size 256]
"""

from __future__ import annotations

import numpy as np

import glraster as gr
from glraster.geometry import synthetic
from glraster.gpu.backends import available_backends
from glraster.studies.registry import argument_parser
from glraster.verify.tolerance import ErrorModel

SCENES = {
    "1000 random triangles, w in [0.2, 20]": [synthetic.random_soup(100, seed=s) for s in range(10)],
    "600 small/sliver triangles (sigma 0.02 NDC)": [
        synthetic.random_soup(100, seed=100 + s, size=0.02) for s in range(6)],
    "grids 20x20 (800 shared-edge triangles each)": [
        synthetic.grid(20, 20, seed=s, w_range=(0.5, 5)) for s in range(3)],
}



def measure(ctx, name: str, parts, size: int) -> None:
    """Print the coverage mismatches and per-output errors of one scene family."""
    errors = {"persp": [], "screen": [], "depth": []}
    mismatch = band = ids = 0
    worst = {k: 0.0 for k in errors}
    for pos, tri in parts:
        gpu = gr.rasterize(pos, tri, (size, size), ctx=ctx)
        ref = gr.reference.rasterize(pos, tri, (size, size))
        rep = gr.compare(gpu, ref, ErrorModel(ulp_factor=1.0))
        mismatch += rep.coverage_mismatch
        band += rep.coverage_mismatch_in_band
        ids += rep.tri_id_mismatch
        same = gpu.mask & ref.mask & (gpu.tri_id == ref.tri_id) & ~ref.depth_tie
        for k in errors:
            errors[k].append(np.abs(getattr(gpu, k) - getattr(ref, k))[same].ravel())
            worst[k] = max(worst[k], rep.values[k].worst_ratio)
    print(f"{name}: coverage mismatches {mismatch} (in band {band}), id mismatches {ids}")
    for k, e in errors.items():
        e = np.concatenate(e)
        print(f"  {k:<7} max {e.max():.2e}  p99.9 {np.percentile(e, 99.9):.2e}  "
              f"mean {e.mean():.2e}  worst error/bound at C=1: {worst[k]:.2f}")


def main(argv=None) -> int:
    parser = argument_parser("core-figures", __doc__)
    parser.add_argument("--backend", default=None, choices=("egl", "osmesa"),
                        help="one backend (default: every backend that works here)")
    parser.add_argument("--size", type=int, default=256, help="image height and width (px)")
    args = parser.parse_args(argv)
    if args.size < 16:
        parser.error(f"--size must be at least 16, got {args.size}")
    for backend in [args.backend] if args.backend else available_backends():
        ctx = gr.Context(backend)
        print(f"\n## {backend}: {ctx.renderer}  ({args.size}x{args.size})")
        try:
            for name, parts in SCENES.items():
                measure(ctx, name, parts, args.size)
        finally:
            ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
