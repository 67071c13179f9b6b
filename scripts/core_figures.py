"""Measure the core figures quoted in README.md: coverage and value error of the GPU
against the float64 reference on random triangles at 256x256, on every backend, and the
tolerance model's calibration (worst error / bound with C = 1).

Run: .venv/bin/python scripts/core_figures.py
"""

from __future__ import annotations

import numpy as np

import glraster as gr
from glraster.geometry import synthetic
from glraster.gpu.backends import available_backends
from glraster.verify.tolerance import ErrorModel

SCENES = {
    "1000 random triangles, w in [0.2, 20]": [synthetic.random_soup(100, seed=s) for s in range(10)],
    "600 small/sliver triangles (sigma 0.02 NDC)": [
        synthetic.random_soup(100, seed=100 + s, size=0.02) for s in range(6)],
    "grids 20x20 (800 shared-edge triangles each)": [
        synthetic.grid(20, 20, seed=s, w_range=(0.5, 5)) for s in range(3)],
}

for backend in available_backends():
    ctx = gr.Context(backend)
    print(f"\n## {backend}: {ctx.renderer}")
    for name, parts in SCENES.items():
        errors = {"persp": [], "screen": [], "depth": []}
        mismatch = band = ids = 0
        worst = {k: 0.0 for k in errors}
        for pos, tri in parts:
            gpu = gr.rasterize(pos, tri, (256, 256), ctx=ctx)
            ref = gr.reference.rasterize(pos, tri, (256, 256))
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
    ctx.release()
